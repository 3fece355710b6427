//! A test rig for the Festo CANopen simulators: a [`Master`] plus a queue of raw PDO frames as
//! one endpoint, one simulated drive, a monitor logging every frame, all on the in-process
//! virtual bus in virtual time. Included by `sim_mtr_dci.rs` and `sim_emca.rs`.
#![allow(dead_code, missing_docs)]

use std::collections::VecDeque;
use std::time::Duration;

use drivers::can::station::{self, Station, Steppable};
use drivers::can::{Bus, ClockMode, Frame, VirtualBus, VirtualBusConfig, VirtualPort};
use drivers::canopen::endpoint::Endpoint;
use drivers::canopen::master::{Master, MasterEvent, Supervision};
use drivers::canopen::nmt::{NmtCommand, NmtTarget};
use drivers::canopen::sdo::{DownloadMode, SdoError};
use drivers::canopen::{Address, NodeId};
use drivers::time::Instant;

pub const MS: Duration = Duration::from_millis(1);

/// The master side: CiA 301 services from [`Master`], PDOs from a queue the test fills.
pub struct Ctl {
    pub master: Master<4, 4, 256>,
    pub pdos: VecDeque<Frame>,
    pub events: Vec<MasterEvent>,
}

impl Endpoint for Ctl {
    fn handle_frame(&mut self, frame: &Frame, now: Instant) {
        self.master.handle_frame(frame, now);
        while let Some(e) = self.master.poll_event() {
            self.events.push(e);
        }
    }
    fn poll_transmit(&mut self, now: Instant) -> Option<Frame> {
        self.master
            .poll_transmit(now)
            .or_else(|| self.pdos.pop_front())
    }
    fn poll_timeout(&self) -> Option<Instant> {
        self.master.poll_timeout()
    }
    fn handle_timeout(&mut self, now: Instant) {
        self.master.handle_timeout(now);
        while let Some(e) = self.master.poll_event() {
            self.events.push(e);
        }
    }
}

pub struct Rig<D: Endpoint> {
    pub bus: VirtualBus,
    pub ctl: Station<VirtualPort, Ctl>,
    pub dev: Station<VirtualPort, D>,
    pub log: Vec<Frame>,
    pub node: NodeId,
    monitor: VirtualPort,
}

impl<D: Endpoint> Rig<D> {
    /// A rig at 1 Mbit/s in virtual time; `make` builds the drive at the bus's start time.
    pub fn new(node: u8, make: impl FnOnce(NodeId, Instant) -> D) -> Rig<D> {
        let cfg = VirtualBusConfig {
            clock: ClockMode::Virtual,
            ..VirtualBusConfig::default()
        };
        let bus = VirtualBus::new(cfg).unwrap();
        let monitor = bus.attach_monitor("monitor");
        let n = NodeId::new(node).unwrap();
        let mut master = Master::default();
        master.add_node(n, Supervision::None, bus.now()).unwrap();
        let ctl = Station::new(
            bus.attach("master"),
            Ctl {
                master,
                pdos: VecDeque::new(),
                events: Vec::new(),
            },
        );
        let dev = Station::new(bus.attach("drive"), make(n, bus.now()));
        Rig {
            bus,
            ctl,
            dev,
            log: Vec::new(),
            node: n,
            monitor,
        }
    }

    /// Every frame seen so far as (COB-ID, data, completion time): what two runs compare.
    pub fn fingerprint(&self) -> Vec<(u16, Vec<u8>, u64)> {
        self.log
            .iter()
            .map(|f| {
                (
                    f.cob_id().unwrap(),
                    f.data().to_vec(),
                    f.timestamp().as_nanos(),
                )
            })
            .collect()
    }

    pub fn now(&self) -> Instant {
        self.bus.now()
    }

    fn settle(&mut self) {
        station::settle(&mut [&mut self.ctl as &mut dyn Steppable, &mut self.dev]);
        while let Ok(Some(f)) = self.monitor.try_recv() {
            self.log.push(f);
        }
    }

    /// Runs until `done` holds (checked after every event) or `limit` passed; whether it held.
    pub fn run_until(
        &mut self,
        limit: Duration,
        mut done: impl FnMut(&mut Rig<D>) -> bool,
    ) -> bool {
        let until = self.now() + limit;
        loop {
            self.settle();
            if done(self) {
                return true;
            }
            if self.now() >= until {
                return false;
            }
            let next = {
                let st: [&mut dyn Steppable; 2] = [&mut self.ctl, &mut self.dev];
                station::next_event(&self.bus, &st, until)
            };
            self.bus.advance_to(next);
        }
    }

    pub fn run_for(&mut self, d: Duration) {
        self.run_until(d, |_| false);
    }

    pub fn nmt(&mut self, cmd: NmtCommand) {
        let n = self.node;
        self.ctl
            .endpoint
            .master
            .nmt(cmd, NmtTarget::Node(n))
            .unwrap();
        self.run_for(2 * MS);
    }

    /// One RPDO (`pdo` 1..=4) with 8 bytes.
    pub fn rpdo(&mut self, pdo: u16, data: [u8; 8]) {
        let id = 0x100 + 0x100 * pdo + u16::from(self.node.get());
        self.ctl.endpoint.pdos.push_back(Frame::std8(id, data));
        self.run_for(MS / 2);
    }

    /// Sends RPDO1 `out` and runs until TPDO1 satisfies `pred`; returns that TPDO's data.
    pub fn pdo1_until(
        &mut self,
        out: [u8; 8],
        limit_ms: u64,
        what: &str,
        pred: impl Fn(&[u8; 8]) -> bool,
    ) -> [u8; 8] {
        let from = self.log.len();
        self.rpdo(1, out);
        let id = 0x180 + u16::from(self.node.get());
        let mut hit = None;
        let mut scan = from;
        let ok = self.run_until(Duration::from_millis(limit_ms), |r| {
            for f in &r.log[scan..] {
                if f.cob_id() == Some(id) && pred(&f.data8()) {
                    hit = Some(f.data8());
                    return true;
                }
            }
            scan = r.log.len();
            false
        });
        assert!(
            ok,
            "{what}: not within {limit_ms} ms; last TPDO1 {:02x?}",
            self.last(id)
        );
        hit.unwrap()
    }

    /// The data of the newest frame with `id` in the log.
    pub fn last(&self, id: u16) -> Option<[u8; 8]> {
        self.log
            .iter()
            .rev()
            .find(|f| f.cob_id() == Some(id))
            .map(|f| f.data8())
    }

    pub fn frames(&self, id: u16, from: usize) -> Vec<Frame> {
        self.log[from..]
            .iter()
            .filter(|f| f.cob_id() == Some(id))
            .copied()
            .collect()
    }

    fn sdo_wait(&mut self) -> Result<Vec<u8>, SdoError> {
        let n = self.node;
        let mut out = None;
        let ok = self.run_until(200 * MS, |r| {
            if let Some(e) = r.ctl.endpoint.master.poll_sdo_event(n) {
                out = Some(e.to_vec());
                true
            } else {
                false
            }
        });
        assert!(ok, "SDO did not complete");
        out.unwrap()
    }

    pub fn sdo_read(&mut self, addr: Address) -> Result<Vec<u8>, SdoError> {
        let n = self.node;
        self.ctl
            .endpoint
            .master
            .sdo(n)
            .unwrap()
            .upload(addr)
            .unwrap();
        self.sdo_wait()
    }

    pub fn sdo_write(&mut self, addr: Address, data: &[u8]) -> Result<(), SdoError> {
        let n = self.node;
        self.ctl
            .endpoint
            .master
            .sdo(n)
            .unwrap()
            .download(addr, data, DownloadMode::Expedited)
            .unwrap();
        self.sdo_wait().map(|_| ())
    }

    /// Writes PNU `pnu` sub `sub` at 2000h + PNU.
    pub fn pnu_write(&mut self, pnu: u16, sub: u8, data: &[u8]) -> Result<(), SdoError> {
        self.sdo_write(Address::new(0x2000 + pnu, sub), data)
    }
}

pub fn pos(s: &[u8; 8]) -> i32 {
    i32::from_le_bytes([s[4], s[5], s[6], s[7]])
}

pub fn rec(ccon: u8, cpos: u8, record: u8) -> [u8; 8] {
    [ccon, cpos, record, 0, 0, 0, 0, 0]
}

pub fn direct(ccon: u8, cpos: u8, cdir: u8, v1: u8, v2: i32) -> [u8; 8] {
    let b = v2.to_le_bytes();
    [ccon, cpos, cdir, v1, b[0], b[1], b[2], b[3]]
}

pub const ACK: u8 = 0x02;
pub const MC: u8 = 0x04;
pub const MOV: u8 = 0x10;
pub const REF: u8 = 0x80;
