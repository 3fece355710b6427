//! The acceptance filter: a station hands its endpoint only the frames the endpoint accepts,
//! and a simulated drive accepts the identifiers its CANopen services answer to, as the
//! acceptance filter of a real drive's CAN controller is set.
#![cfg(feature = "std")]

use std::time::Duration;

use drivers::can::station::{self, Station, Steppable};
use drivers::can::{Bus, Frame, VirtualBus, VirtualBusConfig};
use drivers::canopen::NodeId;
use drivers::canopen::endpoint::Endpoint;
use drivers::sim::mtr_dci::{MtrDci, Profile};
use drivers::sim::tlc5xx::{Tlc5xx, TlcConfig};
use drivers::time::Instant;

fn f(s: &str) -> Frame {
    s.parse().unwrap()
}

/// Accepts the identifiers in `wanted`; records what it was asked and what it was handed.
struct Listener {
    wanted: Vec<u16>,
    asked: std::cell::RefCell<Vec<u16>>,
    handed: Vec<u16>,
}

impl Endpoint for Listener {
    fn accepts(&self, frame: &Frame) -> bool {
        let id = frame.cob_id().unwrap();
        self.asked.borrow_mut().push(id);
        self.wanted.contains(&id)
    }
    fn handle_frame(&mut self, frame: &Frame, _now: Instant) {
        self.handed.push(frame.cob_id().unwrap());
    }
    fn poll_transmit(&mut self, _now: Instant) -> Option<Frame> {
        None
    }
    fn poll_timeout(&self) -> Option<Instant> {
        None
    }
    fn handle_timeout(&mut self, _now: Instant) {}
}

#[test]
fn a_station_hands_over_only_what_its_endpoint_accepts() {
    let bus = VirtualBus::new(VirtualBusConfig::default()).unwrap();
    let mut sender = bus.attach("sender");
    let mut st = Station::new(
        bus.attach("listener"),
        Listener {
            wanted: vec![0x080, 0x205],
            asked: Default::default(),
            handed: Vec::new(),
        },
    );
    for s in [
        "181#0102",
        "080#",
        "201#01",
        "205#0203",
        "605#4000100000000000",
    ] {
        sender.send(&f(s)).unwrap();
    }
    bus.advance_to(bus.now() + Duration::from_millis(5));
    station::settle(&mut [&mut st as &mut dyn Steppable]);
    // Every frame is asked about, in bus order; only the accepted ones are handed over.
    assert_eq!(
        *st.endpoint.asked.borrow(),
        [0x181, 0x080, 0x201, 0x205, 0x605]
    );
    assert_eq!(st.endpoint.handed, [0x080, 0x205]);
}

/// The frames every CANopen device on node 1 answers to, and frames it must refuse (another
/// node's services, its own transmit identifiers other than a PDO's).
const OWN: [&str; 7] = [
    "000#0100", // NMT start, all nodes
    "000#8101", // NMT reset communication, node 1
    "080#",     // SYNC
    "601#4000100000000000",
    "701#R",
    "201#0000000000000000", // RPDO1
    "181#R",                // a remote request on its TPDO1
];
const OTHERS: [&str; 6] = [
    "602#4000100000000000",
    "702#R",
    "202#0000000000000000",
    "182#R",
    "581#4300100000000000", // its own SDO reply identifier: it sends there, never listens
    "285#01",
];

fn check(name: &str, e: &dyn Endpoint) {
    for s in OWN {
        assert!(e.accepts(&f(s)), "{name} refuses {s}");
    }
    for s in OTHERS {
        assert!(!e.accepts(&f(s)), "{name} accepts {s}");
    }
    // Filtered by identifier alone, as a controller does: a data frame on its error-control
    // identifier gets through (the guarding service then ignores it).
    assert!(e.accepts(&f("701#00")), "{name} refuses 701#00");
}

#[test]
fn simulated_drives_accept_their_own_services_only() {
    let node = NodeId::new(1).unwrap();
    let now = Instant::from_nanos(0);
    let tlc = Tlc5xx::new(TlcConfig::new(node), now).unwrap();
    check("TLC5xx", &tlc);
    let mtr = MtrDci::new(node, Profile::Cia402, now).unwrap();
    check("MTR-DCI (CiA 402)", &mtr);
    let mtr = MtrDci::new(node, Profile::Fhpp, now).unwrap();
    check("MTR-DCI (FHPP)", &mtr);
}
