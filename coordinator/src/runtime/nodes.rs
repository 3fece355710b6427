//! The CANopen drives of every bus and their lifecycle, sans-I/O: one [`BootSequencer`] per bus,
//! fed the frames the cycle received (tagged with their bus) and time, handing back the SDO/NMT
//! frames to send and a [`NodeReport`] whenever a drive boots, waits, is lost or is refused.
//!
//! The same value runs inline in virtual time and on the services' executor in real time, so the
//! boot behaves alike under both clocks. What the cycle does with a report is
//! [`apply`]: a booted drive's axis comes online; a waiting, lost or refused one goes offline
//! (refused: faulted `BootFailed`; reset: faulted `DriveReset`).

use drivers::canopen::NodeId;
use drivers::time::{Instant, earliest};

use crate::command::AxisId;
use crate::cycle::{BusFrame, Cycle, Transport};
use crate::event::Event;
use crate::fault::FaultReason;
use crate::runtime::boot::{BootReport, BootSequencer, FailureDetail};
use crate::runtime::plan::MachinePlan;

/// A report of one drive, with its axis and bus.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct NodeReport {
    /// The axis.
    pub axis: AxisId,
    /// The bus, 0-based.
    pub bus: u8,
    /// What happened.
    pub report: BootReport,
}

/// What a report means for the drive.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum NodeStatus {
    /// Booted (again): its axis is in the cycle.
    Running,
    /// Not there (yet, or again): the coordinator keeps asking.
    Waiting,
    /// It reset itself while running; it is being configured again.
    Reset,
    /// Refused (wrong device, configuration refused): waits for its next boot-up.
    Refused,
}

impl NodeReport {
    /// What the report means.
    pub fn status(&self) -> NodeStatus {
        match &self.report.result {
            Ok(()) => NodeStatus::Running,
            Err(e) if e.detail == FailureDetail::UnexpectedBootUp => NodeStatus::Reset,
            Err(e) if e.is_waiting() => NodeStatus::Waiting,
            Err(_) => NodeStatus::Refused,
        }
    }
}

/// Brings the report into the cycle: the axis online, or offline with the fault that says why.
pub fn apply<const A: usize, const G: usize>(
    cycle: &mut Cycle<'_, A, G>,
    axis: AxisId,
    status: NodeStatus,
    now: Instant,
) {
    match status {
        NodeStatus::Running => cycle.set_online(axis, true, now),
        // An axis never booted stays offline without a fault; a lost one is already faulted.
        NodeStatus::Waiting => cycle.set_offline(axis, None),
        NodeStatus::Reset => cycle.set_offline(axis, Some(FaultReason::DriveReset)),
        NodeStatus::Refused => cycle.set_offline(axis, Some(FaultReason::BootFailed)),
    }
}

/// The faults by which the cycle loses a drive: the lifecycle then waits for it.
pub fn is_loss(reason: FaultReason) -> bool {
    matches!(
        reason,
        FaultReason::HeartbeatLost | FaultReason::GuardingLost | FaultReason::LateTpdo(_)
    )
}

/// Every CAN bus's boot sequencer, and which axis each node drives.
pub struct Nodes {
    buses: Vec<BootSequencer>,
    /// Per bus: reports handed out so far.
    handed: Vec<usize>,
    /// Per axis: its bus and node (CANopen axes).
    axes: Vec<Option<(u8, NodeId)>>,
    next_tx: usize,
}

impl std::fmt::Debug for Nodes {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Nodes")
            .field("buses", &self.buses.len())
            .finish_non_exhaustive()
    }
}

impl Nodes {
    /// Starts booting every CANopen axis of `plan` (reset communication to each node).
    pub fn new(plan: &MachinePlan, now: Instant) -> Nodes {
        let mut per_bus: Vec<Vec<_>> = plan.buses.iter().map(|_| Vec::new()).collect();
        let mut axes = Vec::with_capacity(plan.axes.len());
        for a in &plan.axes {
            match (a.setup.transport, &a.boot) {
                (Transport::Can { bus, node }, Some(boot)) => {
                    if let Some(list) = per_bus.get_mut(usize::from(bus)) {
                        list.push(boot.clone());
                    }
                    axes.push(NodeId::new(node).map(|n| (bus, n)));
                }
                _ => axes.push(None),
            }
        }
        Nodes {
            handed: vec![0; per_bus.len()],
            buses: per_bus
                .into_iter()
                .map(|plans| BootSequencer::new(plans, now))
                .collect(),
            axes,
            next_tx: 0,
        }
    }

    /// No drives at all (a machine on Modbus only, tests of the services).
    pub fn none() -> Nodes {
        Nodes {
            buses: Vec::new(),
            handed: Vec::new(),
            axes: Vec::new(),
            next_tx: 0,
        }
    }

    /// One bus (index 0) with these boot plans, each node its own axis in plan order (tests of
    /// the services).
    pub fn single_bus(plans: Vec<crate::runtime::boot::BootPlan>, now: Instant) -> Nodes {
        Nodes {
            axes: plans.iter().map(|p| Some((0, p.node))).collect(),
            handed: vec![0],
            buses: vec![BootSequencer::new(plans, now)],
            next_tx: 0,
        }
    }

    /// Feeds one received frame.
    pub fn handle_frame(&mut self, f: &BusFrame, now: Instant) {
        if let Some(s) = self.buses.get_mut(usize::from(f.bus)) {
            s.handle_frame(&f.frame, now);
        }
    }

    /// The next frame to send: the buses in turn.
    pub fn poll_transmit(&mut self, now: Instant) -> Option<BusFrame> {
        let n = self.buses.len();
        for k in 0..n {
            let b = (self.next_tx + k) % n;
            if let Some(f) = self.buses[b].poll_transmit(now) {
                self.next_tx = (b + 1) % n;
                return Some(BusFrame::new(b as u8, f));
            }
        }
        None
    }

    /// When [`Nodes::handle_timeout`] is next due.
    pub fn poll_timeout(&self) -> Option<Instant> {
        earliest(self.buses.iter().map(|s| s.poll_timeout()))
    }

    /// Runs the timers due at `now`.
    pub fn handle_timeout(&mut self, now: Instant) {
        for s in &mut self.buses {
            if s.poll_timeout().is_some_and(|t| t <= now) {
                s.handle_timeout(now);
            }
        }
    }

    /// The next report not handed out yet.
    pub fn poll_report(&mut self) -> Option<NodeReport> {
        for (b, s) in self.buses.iter().enumerate() {
            while let Some(r) = s.reports().get(self.handed[b]).copied() {
                self.handed[b] += 1;
                // A node planned twice is reported but has no axis of its own.
                if let Some(axis) = self.axes.iter().position(|x| *x == Some((b as u8, r.node))) {
                    return Some(NodeReport {
                        axis: axis as AxisId,
                        bus: b as u8,
                        report: r,
                    });
                }
            }
        }
        None
    }

    /// An event of the cycle: a drive it lost is waited for (and configured again when back).
    pub fn event(&mut self, e: &Event) {
        if let Event::Fault { axis, reason, .. } = *e
            && is_loss(reason)
            && let Some(Some((bus, node))) = self.axes.get(usize::from(axis)).copied()
            && let Some(s) = self.buses.get_mut(usize::from(bus))
        {
            s.lost(node);
        }
    }

    /// Every drive has had its first report (booted, waiting or refused).
    pub fn is_finished(&self) -> bool {
        self.buses.iter().all(|s| s.is_finished())
    }
}
