//! The stepper: one step of the cycle with its frame buffers and counters, shared by both
//! clocks: the frames received since the last step in, [`Cycle::step`], the frames to send out.
//! Allocation-free after [`Stepper::new`].

use drivers::can::Frame;
use drivers::time::{Instant, monotonic_now};
use hdrhistogram::Histogram;

use crate::axis::Image;
use crate::cycle::{BusFrame, Cycle, CycleInput, CycleOutput, ImageInput};
use crate::runtime::plan::{MAX_AXES, MAX_BUSES, MAX_GROUPS, MachinePlan};
use crate::runtime::run::RunError;

/// Frames one cycle may send: a SYNC per bus; RPDO1, RPDO2 (the FPC) and a guarding poll per
/// axis; SDO slots.
pub const TX_CAPACITY: usize = 3 * MAX_AXES + MAX_BUSES + 16;
/// Frames one cycle may receive before the rest waits for the next.
pub const RX_CAPACITY: usize = 4096;

/// A cycle and the inputs of one of its steps, for replay (benchmarks, determinism checks).
#[derive(Clone, Debug)]
pub struct Captured<'t> {
    /// The cycle before the step.
    pub cycle: Box<Cycle<'t, MAX_AXES, MAX_GROUPS>>,
    /// The frames received for the step.
    pub frames: Vec<BusFrame>,
    /// The Modbus images for the step.
    pub images: Vec<ImageInput>,
    /// The step's SYNC time.
    pub now: Instant,
}

/// The per-cycle work shared by both clocks: everything the cycle thread does between
/// receiving and sending. Allocation-free after [`Stepper::new`].
pub struct Stepper<'t> {
    /// The cycle.
    pub cycle: Box<Cycle<'t, MAX_AXES, MAX_GROUPS>>,
    rx: Vec<BusFrame>,
    tx: Vec<BusFrame>,
    modbus_in: Vec<ImageInput>,
    modbus_out: Vec<Image>,
    step_ns: Histogram<u64>,
    /// Frames sent by the coordinator.
    pub frames_sent: u64,
    /// Received frames dropped because more than [`RX_CAPACITY`] arrived in one cycle.
    pub rx_dropped: u64,
    /// Frames the bus refused to queue (a full transmit queue, bus-off).
    pub tx_refused: u64,
    /// Frames received.
    pub frames_received: u64,
    /// The last step's compute time, ns.
    pub last_step_ns: u64,
}

impl std::fmt::Debug for Stepper<'_> {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Stepper").finish_non_exhaustive()
    }
}

impl<'t> Stepper<'t> {
    /// The cycle of `plan`, with every buffer allocated and the Modbus axes online.
    pub fn new(plan: &'t MachinePlan) -> Result<Stepper<'t>, RunError> {
        let axes: Vec<_> = plan.axes.iter().map(|a| a.setup).collect();
        let groups: Vec<_> = plan
            .groups
            .iter()
            .map(|(_, g, t)| (g.clone(), &**t))
            .collect();
        let cycle = Box::new(
            Cycle::new(plan.cycle, &axes, &groups).map_err(|e| RunError::Config(e.to_string()))?,
        );
        let slots = plan.image_slots();
        // Modbus axes come online with their first answer (`CycleLoop`).
        Ok(Stepper {
            cycle,
            rx: Vec::with_capacity(RX_CAPACITY),
            tx: vec![BusFrame::new(0, Frame::std8(0, [0; 8])); TX_CAPACITY],
            modbus_in: vec![ImageInput::default(); slots],
            modbus_out: vec![Image::default(); slots],
            step_ns: Histogram::new_with_bounds(1, 1_000_000_000, 3)
                .map_err(|e| RunError::Config(e.to_string()))?,
            frames_sent: 0,
            rx_dropped: 0,
            tx_refused: 0,
            frames_received: 0,
            last_step_ns: 0,
        })
    }

    /// A copy of the cycle and of the inputs of its next step.
    pub fn capture(&self, now: Instant) -> Captured<'t> {
        Captured {
            cycle: self.cycle.clone(),
            frames: self.rx.clone(),
            images: self.modbus_in.clone(),
            now,
        }
    }

    /// Takes a received frame for the next step, in timestamp order (frames with equal times in
    /// arrival order). A `vbus:` bus delivers frames in the order their senders' processes got
    /// to sending them, and the CANopen services judge every node's deadlines at each frame's
    /// time: after a stall, one node's late-stamped heartbeat handled before another node's
    /// earlier one declared that node lost although its heartbeat was in the same batch.
    pub fn receive(&mut self, f: BusFrame) {
        if self.rx.len() < RX_CAPACITY {
            let t = f.frame.timestamp();
            // Frames come nearly in order: the place is almost always at the end.
            let at = self.rx.partition_point(|x| x.frame.timestamp() <= t);
            self.rx.insert(at, f);
        } else {
            self.rx_dropped += 1;
        }
    }

    /// The counters the shared-memory state carries.
    pub fn counters(&self, skipped: u64, wake_late_us: u32) -> crate::runtime::shm::Counters {
        crate::runtime::shm::Counters {
            frames_sent: self.frames_sent,
            frames_received: self.frames_received,
            tx_refused: self.tx_refused,
            rx_dropped: self.rx_dropped,
            skipped_cycles: skipped,
            step_ns: self.last_step_ns.min(u64::from(u32::MAX)) as u32,
            wake_late_us,
        }
    }

    /// Sets a Modbus slot's input for the next step.
    pub fn image_input(&mut self, slot: usize, m: ImageInput) {
        if let Some(s) = self.modbus_in.get_mut(slot) {
            *s = m;
        }
    }

    /// A Modbus slot's output of the last step.
    pub fn image_output(&self, slot: usize) -> Image {
        self.modbus_out.get(slot).copied().unwrap_or_default()
    }

    /// One step at `now`; returns the frames to send, in order.
    pub fn iterate(&mut self, now: Instant) -> &[BusFrame] {
        let t0 = monotonic_now();
        let mut out = CycleOutput {
            frames: &mut self.tx,
            len: 0,
            overflow: 0,
            images: &mut self.modbus_out,
        };
        self.cycle.step(
            &CycleInput {
                now,
                frames: &self.rx,
                images: &self.modbus_in,
            },
            &mut out,
        );
        let len = out.len;
        let dt = monotonic_now().saturating_duration_since(t0).as_nanos() as u64;
        let _ = self.step_ns.record(dt.max(1));
        self.last_step_ns = dt;
        self.frames_received += self.rx.len() as u64;
        self.rx.clear();
        for m in &mut self.modbus_in {
            m.fresh = false;
        }
        self.frames_sent += len as u64;
        &self.tx[..len]
    }

    /// Step time: median, p99, max, ns.
    pub fn step_figures(&self) -> (u64, u64, u64) {
        let h = &self.step_ns;
        (h.value_at_quantile(0.5), h.value_at_quantile(0.99), h.max())
    }
}
