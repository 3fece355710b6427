//! Helpers shared by the integration tests in `tests/tests/`: a CANopen test device, and a rig
//! that runs a master and devices on the in-process virtual bus in virtual time.

use std::time::Duration;

use drivers::can::station::{self, Station, Steppable};
use drivers::can::{ClockMode, Frame, VirtualBus, VirtualBusConfig, VirtualPort};
use drivers::canopen::device::{
    CommProfile, Device, NoHooks, PdoDefault, insert_communication_objects,
};
use drivers::canopen::master::{Master, Supervision};
use drivers::canopen::od::{AccessType, DataType, EntryDef, ObjectDictionary, Value};
use drivers::canopen::sdo::SdoClientConfig;
use drivers::canopen::{Address, NodeId};
use drivers::time::Instant;

/// The dictionary of the test device: 160 entries, 16 KiB of values.
pub type TestOd = ObjectDictionary<'static, 160, 16384>;
/// The test device: SDO downloads up to 4 KiB.
pub type TestDevice = Device<'static, 160, 16384, 4096, NoHooks>;
/// The test master: 8 nodes, 8 queued SDO requests of up to 4 KiB each.
pub type TestMaster = Master<8, 8, 4096>;

/// A 1 KiB read-only DOMAIN.
pub const DOMAIN_1K: Address = Address::new(0x2000, 0);
/// A 4 KiB writable DOMAIN.
pub const DOMAIN_4K: Address = Address::new(0x2001, 0);
/// Controlword (RPDO-mappable).
pub const CONTROLWORD: Address = Address::new(0x6040, 0);
/// Statusword (TPDO-mappable).
pub const STATUSWORD: Address = Address::new(0x6041, 0);
/// Position actual value (TPDO-mappable).
pub const POSITION: Address = Address::new(0x6064, 0);
/// Target position (RPDO-mappable).
pub const TARGET: Address = Address::new(0x607A, 0);
/// A digital input byte, mapped bit-wise in tests.
pub const INPUTS: Address = Address::new(0x60FD, 0);

/// The 1 KiB pattern stored in [`DOMAIN_1K`].
pub static PATTERN_1K: [u8; 1024] = {
    let mut a = [0u8; 1024];
    let mut i = 0;
    while i < 1024 {
        a[i] = (i * 7 + 3) as u8;
        i += 1;
    }
    a
};

/// The communication profile of the test device: TLC5xx-like PDO defaults (only PDO1 valid).
pub const PROFILE: CommProfile = CommProfile {
    rpdo: [
        PdoDefault {
            valid: true,
            transmission: 255,
            event_ms: 0,
            mapping: &[0x6040_0010],
            fixed: false,
        },
        PdoDefault {
            valid: false,
            transmission: 0,
            event_ms: 0,
            mapping: &[0x6040_0010, 0x607A_0020],
            fixed: false,
        },
        PdoDefault::ABSENT,
        PdoDefault::ABSENT,
    ],
    tpdo: [
        PdoDefault {
            valid: true,
            transmission: 255,
            event_ms: 0,
            mapping: &[0x6041_0010],
            fixed: false,
        },
        PdoDefault {
            valid: false,
            transmission: 0,
            event_ms: 0,
            mapping: &[0x6041_0010, 0x6064_0020],
            fixed: false,
        },
        PdoDefault::ABSENT,
        PdoDefault::ABSENT,
    ],
    identity: [0x0000_0059, 0x0005_0001, 0x0001_0000, 0x1234_5678],
    ..CommProfile::basic(0x0002_0192)
};

/// The test device's dictionary for `node`.
pub fn test_od(node: NodeId) -> TestOd {
    let mut od = TestOd::new();
    insert_communication_objects(&mut od, node, &PROFILE).expect("communication objects fit");
    let defs = [
        EntryDef::new(DOMAIN_1K, "1 KiB domain", DataType::Domain, AccessType::Ro)
            .capacity(1024)
            .default_value(Value::Bytes(&PATTERN_1K)),
        EntryDef::new(DOMAIN_4K, "4 KiB domain", DataType::Domain, AccessType::Rw).capacity(4096),
        EntryDef::new(
            CONTROLWORD,
            "controlword",
            DataType::Unsigned16,
            AccessType::Rww,
        )
        .mappable(),
        EntryDef::new(
            STATUSWORD,
            "statusword",
            DataType::Unsigned16,
            AccessType::Rwr,
        )
        .mappable()
        .default_value(Value::Unsigned(0x0040)),
        EntryDef::new(
            POSITION,
            "position actual value",
            DataType::Integer32,
            AccessType::Rwr,
        )
        .mappable(),
        EntryDef::new(
            TARGET,
            "target position",
            DataType::Integer32,
            AccessType::Rww,
        )
        .mappable(),
        EntryDef::new(
            INPUTS,
            "digital inputs",
            DataType::Unsigned8,
            AccessType::Rwr,
        )
        .mappable(),
        EntryDef::new(
            Address::new(0x6083, 0),
            "profile acceleration",
            DataType::Unsigned32,
            AccessType::Rw,
        ),
        EntryDef::new(
            Address::new(0x6060, 0),
            "modes of operation",
            DataType::Integer8,
            AccessType::Rw,
        ),
    ];
    od.insert_all(&defs).expect("application objects fit");
    od
}

/// A powered-on test device.
pub fn test_device(node: NodeId, now: Instant) -> TestDevice {
    let mut d = TestDevice::new(node, test_od(node), PROFILE.boot_up, NoHooks);
    d.power_on(now);
    d
}

/// `n` as a node-ID.
pub fn node(n: u8) -> NodeId {
    NodeId::new(n).expect("valid node-ID")
}

/// A master and devices on one virtual-time bus, plus a monitor port that records every frame.
pub struct Rig {
    /// The bus.
    pub bus: VirtualBus,
    /// The master's station.
    pub master: Station<VirtualPort, Box<TestMaster>>,
    /// The devices' stations.
    pub devices: Vec<Station<VirtualPort, Box<TestDevice>>>,
    /// Every frame seen on the bus, in order, with its completion time.
    pub log: Vec<Frame>,
    monitor: VirtualPort,
}

impl Rig {
    /// A 1 Mbit/s bus with a master and one test device per node-ID in `nodes`.
    pub fn new(nodes: &[u8]) -> Rig {
        Self::with_bitrate(nodes, 1_000_000)
    }

    /// The same at another bitrate.
    pub fn with_bitrate(nodes: &[u8], bitrate: u32) -> Rig {
        let cfg = VirtualBusConfig {
            bitrate,
            clock: ClockMode::Virtual,
            ..VirtualBusConfig::default()
        };
        let bus = VirtualBus::new(cfg).expect("valid bus configuration");
        let monitor = bus.attach_monitor("monitor");
        let mut m = Box::new(TestMaster::new(SdoClientConfig::default(), true));
        for &n in nodes {
            m.add_node(node(n), Supervision::None, bus.now())
                .expect("room for the node");
        }
        let master = Station::new(bus.attach("master"), m);
        let devices = nodes
            .iter()
            .map(|&n| {
                Station::new(
                    bus.attach(&format!("node{n}")),
                    Box::new(test_device(node(n), bus.now())),
                )
            })
            .collect();
        Rig {
            bus,
            master,
            devices,
            log: Vec::new(),
            monitor,
        }
    }

    /// The current bus time.
    pub fn now(&self) -> Instant {
        self.bus.now()
    }

    /// The device with node-ID `n`.
    pub fn device(&mut self, n: u8) -> &mut TestDevice {
        let st = self
            .devices
            .iter_mut()
            .find(|s| s.endpoint.node().get() == n)
            .expect("device on the rig");
        &mut st.endpoint
    }

    fn stations(&mut self) -> Vec<&mut dyn Steppable> {
        let mut v: Vec<&mut dyn Steppable> = vec![&mut self.master];
        v.extend(self.devices.iter_mut().map(|d| d as &mut dyn Steppable));
        v
    }

    fn settle(&mut self) {
        station::settle(&mut self.stations());
        while let Ok(Some(f)) = drivers::can::Bus::try_recv(&mut self.monitor) {
            self.log.push(f);
        }
    }

    /// Runs event by event until `done` returns true (checked after each settled instant) or
    /// `limit` of bus time passes. Returns whether `done` became true.
    pub fn run_until(&mut self, limit: Duration, mut done: impl FnMut(&mut Rig) -> bool) -> bool {
        let until = self.now() + limit;
        loop {
            self.settle();
            if done(self) {
                return true;
            }
            if self.now() >= until {
                return false;
            }
            let bus = self.bus.clone();
            let next = station::next_event(&bus, &self.stations(), until);
            bus.advance_to(next);
        }
    }

    /// Runs for `d` of bus time.
    pub fn run_for(&mut self, d: Duration) {
        self.run_until(d, |_| false);
    }

    /// Frames of the log with COB-ID `id`, from index `from` on.
    pub fn frames_with_id(&self, id: u16, from: usize) -> Vec<Frame> {
        self.log[from..]
            .iter()
            .filter(|f| f.cob_id() == Some(id))
            .copied()
            .collect()
    }
}

/// A frame from `cansend` text, for expectations.
pub fn frame(s: &str) -> Frame {
    s.parse().expect("valid frame text")
}
