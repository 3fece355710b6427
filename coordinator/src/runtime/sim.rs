//! The simulated drives behind a machine plan: every CANopen axis gets its device's simulator
//! on the virtual bus, every Modbus axis a simulated CMMO-ST (in memory in virtual time, a
//! Modbus TCP server on loopback in real time). The coordinator talks to them exactly as it
//! would to the real drives: frames on the bus, Modbus ADUs.

use std::sync::{Arc, Mutex};

use drivers::can::Frame;
use drivers::can::station::{self, Station, Steppable};
use drivers::can::{PortId, VirtualBus, VirtualPort};
use drivers::canopen::NodeId;
use drivers::canopen::endpoint::Endpoint;
use drivers::canopen::sync::{SyncCobId, SyncProducer};
use drivers::modbus::client::Client;
use drivers::sim::cia402_drive::{Cia402Config, Cia402Drive};
use drivers::sim::cmmo_st::mbap::MAX_ADU;
use drivers::sim::cmmo_st::{self, Server, ServerConfig, Session};
use drivers::sim::emca::Emca;
use drivers::sim::fhpp_drive::FhppDrive;
use drivers::sim::mtr_dci::MtrDci;
use drivers::sim::tlc5xx::{Tlc5xx, TlcConfig};
use drivers::time::Instant;

use crate::axis::{DeviceKind, Profile};
use crate::cycle::Transport;
use crate::runtime::plan::MachinePlan;

/// Stations of one bus listed without an allocation in `SimBus::run_until`.
const INLINE_STATIONS: usize = 8;

/// A simulated CANopen drive on its bus port.
pub enum SimDrive {
    /// Festo MTR-DCI (boxed: the simulators are tens of kilobytes each).
    MtrDci(Box<Station<VirtualPort, MtrDci>>),
    /// Festo EMCA.
    Emca(Box<Station<VirtualPort, Emca>>),
    /// Schneider TLC5xx.
    Tlc5xx(Box<Station<VirtualPort, Tlc5xx>>),
    /// A generic CiA 402 drive (the built-in dictionary, or its EDS's).
    Cia402(Box<Station<VirtualPort, Cia402Drive>>),
}

impl std::fmt::Debug for SimDrive {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        let kind = match self {
            SimDrive::MtrDci(_) => "MTR-DCI",
            SimDrive::Emca(_) => "EMCA",
            SimDrive::Tlc5xx(_) => "TLC5xx",
            SimDrive::Cia402(_) => "CiA 402 drive",
        };
        write!(f, "SimDrive({kind})")
    }
}

impl SimDrive {
    /// Which simulator runs the drive: drives of one kind run the same code.
    fn kind(&self) -> u8 {
        match self {
            SimDrive::MtrDci(_) => 0,
            SimDrive::Emca(_) => 1,
            SimDrive::Tlc5xx(_) => 2,
            SimDrive::Cia402(_) => 3,
        }
    }

    fn steppable(&mut self) -> &mut dyn Steppable {
        match self {
            SimDrive::MtrDci(s) => s.as_mut(),
            SimDrive::Emca(s) => s.as_mut(),
            SimDrive::Tlc5xx(s) => s.as_mut(),
            SimDrive::Cia402(s) => s.as_mut(),
        }
    }
    /// The drive's bus port (to disconnect it in a test).
    pub fn port(&self) -> PortId {
        match self {
            SimDrive::MtrDci(s) => s.bus.id(),
            SimDrive::Emca(s) => s.bus.id(),
            SimDrive::Tlc5xx(s) => s.bus.id(),
            SimDrive::Cia402(s) => s.bus.id(),
        }
    }
    /// The FHPP behaviour of a Festo drive.
    pub fn fhpp_mut(&mut self) -> Option<&mut FhppDrive> {
        match self {
            SimDrive::MtrDci(s) => Some(s.endpoint.drive_mut()),
            SimDrive::Emca(s) => Some(s.endpoint.drive_mut()),
            SimDrive::Tlc5xx(_) | SimDrive::Cia402(_) => None,
        }
    }
    /// The TLC5xx simulator.
    pub fn tlc_mut(&mut self) -> Option<&mut Tlc5xx> {
        match self {
            SimDrive::Tlc5xx(s) => Some(&mut s.endpoint),
            _ => None,
        }
    }
    /// The generic CiA 402 drive's simulator.
    pub fn cia402_mut(&mut self) -> Option<&mut Cia402Drive> {
        match self {
            SimDrive::Cia402(s) => Some(&mut s.endpoint),
            _ => None,
        }
    }
}

/// Another node producing SYNC (a PLC, another master): what a coordinator in SYNC-consumer
/// mode follows. Simulated with the stack's own SYNC producer.
#[derive(Debug)]
pub struct ExternalSync {
    producer: SyncProducer,
}

impl ExternalSync {
    /// A producer of SYNC every `period`, the first at `first`.
    pub fn new(period: std::time::Duration, first: Instant) -> Result<ExternalSync, String> {
        let cob = SyncCobId {
            producer: true,
            id: 0x080,
        };
        let mut producer = SyncProducer::new(cob, period.as_micros() as u32, 0)
            .map_err(|e| format!("SYNC producer: {e}"))?;
        producer.start(first);
        Ok(ExternalSync { producer })
    }
}

impl Endpoint for ExternalSync {
    fn handle_frame(&mut self, _frame: &Frame, _now: Instant) {}
    fn poll_transmit(&mut self, now: Instant) -> Option<Frame> {
        self.producer.poll_transmit(now)
    }
    fn poll_timeout(&self) -> Option<Instant> {
        self.producer.poll_timeout()
    }
    fn handle_timeout(&mut self, _now: Instant) {}
}

/// The simulated CANopen drives (and, for a SYNC consumer, the SYNC producer it follows).
#[derive(Debug)]
pub struct SimBus {
    /// One drive per CANopen axis: the axis name and the drive.
    pub drives: Vec<(String, SimDrive)>,
    /// The external SYNC producer (SYNC-consumer mode only).
    pub sync: Option<Box<Station<VirtualPort, ExternalSync>>>,
}

impl SimBus {
    /// Builds a simulator for every CANopen axis of `plan` on bus `index`, attached to `bus`,
    /// powered on at `now`.
    pub fn build(
        bus: &VirtualBus,
        plan: &MachinePlan,
        index: usize,
        now: Instant,
    ) -> Result<SimBus, String> {
        let mut drives = Vec::new();
        for a in &plan.axes {
            let Transport::Can { bus: b, node } = a.setup.transport else {
                continue;
            };
            if usize::from(b) != index {
                continue;
            }
            let id = NodeId::new(node).ok_or_else(|| format!("node {node}"))?;
            let port = bus.attach(&format!("sim-{}", a.name));
            let err = |e: &dyn std::fmt::Display| format!("simulator of {}: {e}", a.name);
            // The simulators model exactly the catalog's profiles (`drivers::catalog`).
            if !a.setup.kind.device().offers(a.setup.profile) {
                return Err(err(&format_args!(
                    "the {} does not offer the {} profile",
                    a.setup.kind,
                    a.setup.profile.label()
                )));
            }
            let d = match (a.setup.kind, a.setup.profile) {
                (DeviceKind::MtrDci, p) => {
                    let p = match p {
                        Profile::Fhpp => drivers::sim::mtr_dci::Profile::Fhpp,
                        Profile::Cia402 => drivers::sim::mtr_dci::Profile::Cia402,
                    };
                    SimDrive::MtrDci(Box::new(Station::new(
                        port,
                        MtrDci::new(id, p, now).map_err(|e| err(&e))?,
                    )))
                }
                (DeviceKind::Emca, _) => SimDrive::Emca(Box::new(Station::new(
                    port,
                    Emca::new(id, now).map_err(|e| err(&e))?,
                ))),
                (DeviceKind::Tlc5xx, _) => SimDrive::Tlc5xx(Box::new(Station::new(
                    port,
                    Tlc5xx::new(TlcConfig::new(id), now).map_err(|e| err(&e))?,
                ))),
                (DeviceKind::CmmoSt, _) => continue,
                // The built-in generic drive: a simulated bus has no EDS to take one from.
                (DeviceKind::Cia402, _) => SimDrive::Cia402(Box::new(Station::new(
                    port,
                    Cia402Drive::new(Cia402Config::new(id), now).map_err(|e| err(&e))?,
                ))),
            };
            drives.push((a.name.clone(), d));
        }
        let sync = if plan.cycle.sync_producer {
            None
        } else {
            // The external producer starts one cycle in, so the drives have booted into a
            // running bus as they would on a machine.
            let port = bus.attach("sync-producer");
            Some(Box::new(Station::new(
                port,
                ExternalSync::new(plan.period, now + plan.period)?,
            )))
        };
        Ok(SimBus { drives, sync })
    }

    /// The simulators of the bus's drives, in order: buses alike in this run the same code.
    pub fn kinds(&self) -> Vec<u8> {
        self.drives.iter().map(|(_, d)| d.kind()).collect()
    }

    /// The drive of an axis.
    pub fn drive_mut(&mut self, axis: &str) -> Option<&mut SimDrive> {
        self.drives
            .iter_mut()
            .find(|(n, _)| n == axis)
            .map(|(_, d)| d)
    }

    fn refs(&mut self) -> Vec<&mut dyn Steppable> {
        let mut v: Vec<&mut dyn Steppable> =
            self.drives.iter_mut().map(|(_, d)| d.steppable()).collect();
        if let Some(s) = &mut self.sync {
            v.push(s.as_mut());
        }
        v
    }

    /// Runs the drives on a virtual-time bus up to `until`.
    pub fn run_until(&mut self, bus: &VirtualBus, until: Instant) {
        // Once per bus and cycle: the usual few stations are listed on the stack, not in a
        // fresh allocation.
        let mut inline = heapless::Vec::<&mut dyn Steppable, INLINE_STATIONS>::new();
        if self.drives.len() + usize::from(self.sync.is_some()) <= INLINE_STATIONS {
            for (_, d) in self.drives.iter_mut() {
                let _ = inline.push(d.steppable());
            }
            if let Some(s) = &mut self.sync {
                let _ = inline.push(s.as_mut());
            }
            station::run_until(bus, &mut inline, until);
            return;
        }
        let mut refs = self.refs();
        station::run_until(bus, &mut refs, until);
    }

    /// Real time: lets the drives act on what arrived and returns their next deadline.
    pub fn settle(&mut self) -> Option<Instant> {
        let mut refs = self.refs();
        station::settle(&mut refs);
        refs.iter().filter_map(|s| s.next_deadline()).min()
    }
}

/// A simulated CMMO-ST reached in memory: the same Modbus ADUs as over TCP, handed to the
/// device's session directly so that virtual time stays deterministic.
pub struct InMemoryCmmo {
    session: Session,
    drive: FhppDrive,
    client: Client,
    buf: [u8; MAX_ADU],
    silent: bool,
}

impl std::fmt::Debug for InMemoryCmmo {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str("InMemoryCmmo")
    }
}

impl InMemoryCmmo {
    /// A powered-on CMMO-ST with the factory interface settings, connected.
    pub fn new(now: Instant) -> Result<InMemoryCmmo, String> {
        let mut session =
            Session::new(cmmo_st::Config::default()).map_err(|e| format!("CMMO-ST: {e}"))?;
        let mut drive = cmmo_st::drive::commissioned().map_err(|e| e.to_string())?;
        session.connect(&mut drive, now);
        Ok(InMemoryCmmo {
            session,
            drive,
            client: Client::new(0),
            buf: [0; MAX_ADU],
            silent: false,
        })
    }

    /// One FC 0x17 exchange at `now`: writes `output`, returns the status image (`None` if
    /// the device did not answer or answered with an exception).
    pub fn exchange(&mut self, output: &[u8; 8], now: Instant) -> Option<[u8; 8]> {
        if self.silent {
            self.step_to(now);
            return None;
        }
        let mut req = [0u8; MAX_ADU];
        let n = self.client.exchange_image(output, &mut req).ok()?;
        let len = self
            .session
            .handle_frame(&req[..n], &mut self.drive, now, &mut self.buf)
            .ok()??;
        self.client
            .handle_response(&self.buf[..len])
            .ok()
            .and_then(|r| r.image())
    }

    /// Stops (or resumes) answering, as a device whose network went away.
    pub fn set_silent(&mut self, silent: bool) {
        self.silent = silent;
    }

    /// The simulated drive.
    pub fn drive_mut(&mut self) -> &mut FhppDrive {
        &mut self.drive
    }

    /// Advances the drive to `now` without an exchange.
    pub fn step_to(&mut self, now: Instant) {
        self.drive.step_to(now);
    }
}

/// Starts a simulated CMMO-ST Modbus TCP server on 127.0.0.1 (an OS-chosen port).
pub fn spawn_cmmo_server() -> Result<Server, String> {
    let drive = cmmo_st::drive::commissioned().map_err(|e| e.to_string())?;
    Server::spawn(ServerConfig::loopback(0), Arc::new(Mutex::new(drive)))
        .map_err(|e| format!("CMMO-ST server: {e}"))
}

/// The port the coordinator uses on a virtual bus.
pub fn coordinator_port(bus: &VirtualBus) -> VirtualPort {
    bus.attach("coordinator")
}
