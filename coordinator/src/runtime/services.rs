//! The non-real-time side of the coordinator: static tasks on an embassy executor (platform
//! std, one thread) that talk to the cycle thread only through single-producer single-consumer
//! queues (`heapless::spsc`), so the cycle never locks, allocates or waits for them.
//!
//! [`channels`] creates the queues once, in a leaked `'static` block, and splits them into the
//! cycle thread's halves ([`CycleEnds`]), the services' halves ([`ServiceEnds`]) and the
//! clients' end of the command path ([`CommandPort`]: the shared-memory command server owns it
//! and puts each client's command straight into the cycle's request queue; no task relays
//! them). [`spawn_services`] starts the executor thread with two tasks:
//!
//! - **boot**: runs the drives' boot and lifecycle ([`Nodes`]: a boot sequencer per bus) over
//!   the frame queues (it sends SDO/NMT frames the cycle puts on their bus after its PDOs, and
//!   receives the SDO answers, boot-ups and EMCYs the cycle forwards), with embassy timers for
//!   its timeouts, and hands every [`NodeReport`] to the cycle so it brings a booted axis
//!   online or takes a lost one out. Drives the cycle loses (its fault events) are waited for
//!   and configured again when they come back. It also reports EMCYs.
//! - **events**: takes the cycle's [`Event`]s and hands them to the sink.
//!
//! The queues from the cycle are polled every [`SERVICE_TICK`]: the cycle cannot wake an async
//! task without a waker, which would mean a futex call on the real-time thread (the design
//! keeps syscalls off it); a millisecond of latency is nothing for services. The boot's own
//! timeouts are embassy timers (docs/decisions.md).

use std::cell::RefCell;
use std::rc::Rc;
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, AtomicUsize, Ordering};
use std::thread::JoinHandle;
use std::time::Duration;

use drivers::can::Frame;
use drivers::canopen::ids;
use drivers::time::monotonic_now;
use heapless::spsc::{Consumer, Producer, Queue};

use super::nodes::{NodeReport, Nodes};
use crate::command::{Answer, Command, Request};
use crate::cycle::BusFrame;
use crate::event::Event;

/// Requests the cycle can have waiting (services → cycle).
pub const REQUESTS: usize = 32;
/// Answers the services can have waiting (cycle → services).
pub const ANSWERS: usize = 32;
/// Events the services can have waiting (cycle → services): a burst of state changes of a
/// large machine in one cycle fits.
pub const EVENTS: usize = 128;
/// Frames the cycle can have waiting to send (services → cycle): SDO and NMT only, at most a
/// few per node at a time.
pub const TX_FRAMES: usize = 64;
/// Received frames waiting for the services (cycle → services): SDO answers, boot-ups and
/// heartbeats/guarding replies, EMCYs; room for several cycles of them.
pub const RX_FRAMES: usize = 128;
/// Boot reports waiting for the cycle (one per node).
pub const BOOT_REPORTS: usize = 32;
/// How often the tasks look at the queues.
pub const SERVICE_TICK: Duration = Duration::from_millis(1);

// heapless 0.9's spsc queue of N slots holds N - 1 items.
struct Queues {
    requests: Queue<Request, { REQUESTS + 1 }>,
    answers: Queue<Answer, { ANSWERS + 1 }>,
    events: Queue<Event, { EVENTS + 1 }>,
    tx_frames: Queue<BusFrame, { TX_FRAMES + 1 }>,
    rx_frames: Queue<BusFrame, { RX_FRAMES + 1 }>,
    boot_reports: Queue<QueuedReport, { BOOT_REPORTS + 1 }>,
}

/// A drive report on its way to the cycle, with how many frames the services had queued for
/// the buses when it was made. A drive is done when its NMT start has been handed out, but that
/// frame still waits in [`TX_FRAMES`] behind others (the cycle sends only a few per cycle): the
/// cycle brings the axis online, and starts expecting its TPDOs, only once it has sent that
/// many. (Without this, six drives booted in lockstep came online up to two cycles before their
/// NMT start went out and all faulted `no TPDO for 3 cycles`.)
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct QueuedReport {
    /// The report.
    pub report: NodeReport,
    /// Frames queued for the cycle to send (counted from the start) when it was made.
    pub after_frames: u64,
}

/// A queue was full: the item was not queued (and is handed back where that helps).
#[derive(Debug, Clone, Copy, PartialEq, Eq, thiserror::Error)]
#[error("the {queue} queue is full ({capacity} entries)")]
pub struct QueueFull {
    /// Which queue.
    pub queue: &'static str,
    /// Its capacity.
    pub capacity: usize,
}

/// The cycle thread's halves of the queues. Every method is allocation-free, lock-free and
/// never waits, so the cycle step may call them.
pub struct CycleEnds {
    /// Requests from the services ([`CycleEnds::request`], which keeps room for the answer).
    requests: Consumer<'static, Request>,
    /// Answers to the services.
    pub answers: Producer<'static, Answer>,
    /// Events to the services.
    pub events: Producer<'static, Event>,
    /// SDO/NMT frames to put on their bus after the cycle's PDOs ([`CycleEnds::tx_frame`]).
    tx_frames: Consumer<'static, BusFrame>,
    /// Received frames for the services (see [`is_service_frame`]).
    pub rx_frames: Producer<'static, BusFrame>,
    /// Drive reports ([`CycleEnds::boot_report`]).
    boot_reports: Consumer<'static, QueuedReport>,
    /// Frames taken from `tx_frames` so far.
    sent: u64,
}

impl core::fmt::Debug for CycleEnds {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        f.debug_struct("CycleEnds").finish_non_exhaustive()
    }
}

impl CycleEnds {
    /// The next SDO/NMT frame to put on its bus after the cycle's PDOs.
    pub fn tx_frame(&mut self) -> Option<BusFrame> {
        let f = self.tx_frames.dequeue()?;
        self.sent += 1;
        Some(f)
    }

    /// The next drive report, once every frame queued before it (the node's NMT start among
    /// them) has been taken with [`CycleEnds::tx_frame`].
    pub fn boot_report(&mut self) -> Option<NodeReport> {
        if self.boot_reports.peek()?.after_frames > self.sent {
            return None;
        }
        self.boot_reports.dequeue().map(|q| q.report)
    }

    /// Hands a received frame to the services if it is theirs ([`is_service_frame`]); `Ok(false)`
    /// if it is not, `Err` if their queue is full (the frame is dropped; count it).
    pub fn offer_received(&mut self, frame: &BusFrame) -> Result<bool, QueueFull> {
        if !is_service_frame(&frame.frame) {
            return Ok(false);
        }
        self.rx_frames
            .enqueue(*frame)
            .map(|()| true)
            .map_err(|_| QueueFull {
                queue: "received frames",
                capacity: RX_FRAMES,
            })
    }

    /// The next request, only while its answer has room in the answers queue: a request the
    /// cycle takes (and answers before it takes the next) is always answered (a full answers
    /// queue would drop the answer, and the client would wait in vain); the others wait in
    /// their queue for the next cycle.
    pub fn request(&mut self) -> Option<Request> {
        if !self.answers.ready() {
            return None;
        }
        self.requests.dequeue()
    }

    /// Queues an answer for the services.
    pub fn answer(&mut self, answer: Answer) -> Result<(), QueueFull> {
        self.answers.enqueue(answer).map_err(|_| QueueFull {
            queue: "answers",
            capacity: ANSWERS,
        })
    }

    /// Queues an event for the services.
    pub fn event(&mut self, event: Event) -> Result<(), QueueFull> {
        self.events.enqueue(event).map_err(|_| QueueFull {
            queue: "events",
            capacity: EVENTS,
        })
    }
}

/// The services' halves of the queues; given to [`spawn_services`].
pub struct ServiceEnds {
    /// Events from the cycle.
    pub events: Consumer<'static, Event>,
    /// SDO/NMT frames for the cycle to send.
    pub tx_frames: Producer<'static, BusFrame>,
    /// Frames the cycle received for the services.
    pub rx_frames: Consumer<'static, BusFrame>,
    /// Drive reports for the cycle.
    pub boot_reports: Producer<'static, QueuedReport>,
}

impl core::fmt::Debug for ServiceEnds {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        f.debug_struct("ServiceEnds").finish_non_exhaustive()
    }
}

/// Creates the queues (leaked: they live as long as the program, which is what the cycle
/// thread needs; call it once per machine) and splits them.
pub fn channels() -> (CycleEnds, ServiceEnds, CommandPort) {
    let q: &'static mut Queues = Box::leak(Box::new(Queues {
        requests: Queue::new(),
        answers: Queue::new(),
        events: Queue::new(),
        tx_frames: Queue::new(),
        rx_frames: Queue::new(),
        boot_reports: Queue::new(),
    }));
    let (req_p, req_c) = q.requests.split();
    let (ans_p, ans_c) = q.answers.split();
    let (ev_p, ev_c) = q.events.split();
    let (tx_p, tx_c) = q.tx_frames.split();
    let (rx_p, rx_c) = q.rx_frames.split();
    let (br_p, br_c) = q.boot_reports.split();
    (
        CycleEnds {
            requests: req_c,
            answers: ans_p,
            events: ev_p,
            tx_frames: tx_c,
            rx_frames: rx_p,
            boot_reports: br_c,
            sent: 0,
        },
        ServiceEnds {
            events: ev_c,
            tx_frames: tx_p,
            rx_frames: rx_c,
            boot_reports: br_p,
        },
        CommandPort {
            requests: req_p,
            answers: ans_c,
            next_tag: 1,
        },
    )
}

/// The clients' end of the command path: one thread (the shared-memory command server) owns
/// it and puts each client's command straight into the cycle's request queue, and takes the
/// cycle's answers back, matched by tag. Nothing stands between a client and the cycle's
/// admission but this queue. Lock-free and allocation-free.
pub struct CommandPort {
    requests: Producer<'static, Request>,
    answers: Consumer<'static, Answer>,
    next_tag: u64,
}

impl core::fmt::Debug for CommandPort {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        f.debug_struct("CommandPort").finish_non_exhaustive()
    }
}

impl CommandPort {
    /// Queues `command` for the cycle; its answer will carry the returned tag. `Err` when the
    /// cycle has [`REQUESTS`] waiting already (it is not keeping up): refuse the client at once.
    pub fn submit(&mut self, command: Command) -> Result<u64, QueueFull> {
        let tag = self.next_tag;
        self.requests
            .enqueue(Request { tag, command })
            .map_err(|_| QueueFull {
                queue: "requests",
                capacity: REQUESTS,
            })?;
        self.next_tag = self.next_tag.wrapping_add(1);
        Ok(tag)
    }

    /// The next answer of the cycle, if any.
    pub fn answer(&mut self) -> Option<Answer> {
        self.answers.dequeue()
    }
}

/// Whether a received frame is the services' business: SDO answers (580h + n), NMT error
/// control (700h + n: boot-ups, heartbeats, guarding replies) and EMCY / legacy boot-ups
/// (80h + n). Pure and cheap, for the cycle.
pub fn is_service_frame(frame: &Frame) -> bool {
    let Some(id) = frame.cob_id() else {
        return false;
    };
    let node = id & 0x7F;
    node != 0 && matches!(id & !0x7F, ids::SDO_TX | ids::NMT_ERROR_CONTROL | ids::EMCY)
}

/// What the services report to the sink.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum ServiceEvent {
    /// An event of the cycle.
    Cycle(Event),
    /// A drive booted, is waited for, was lost, reset itself or was refused.
    Node(NodeReport),
    /// Every planned drive has its first report.
    BootFinished,
    /// An EMCY frame arrived (after the boot): node, error code, error register.
    Emcy {
        /// The node.
        node: u8,
        /// The error code.
        code: u16,
        /// 1001h.
        register: u8,
    },
}

impl core::fmt::Display for ServiceEvent {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        match self {
            ServiceEvent::Cycle(e) => write!(f, "{e}"),
            ServiceEvent::Node(r) => write!(f, "{}", r.report),
            ServiceEvent::BootFinished => f.write_str("boot finished"),
            ServiceEvent::Emcy {
                node,
                code,
                register,
            } => write!(
                f,
                "node {node}: EMCY {code:04X}h, error register {register:02X}h"
            ),
        }
    }
}

/// Where the services' reports go (called on the executor thread).
pub type Sink = Box<dyn FnMut(ServiceEvent) + Send>;

/// The running services: the way to stop them.
#[derive(Debug)]
pub struct ServicesHandle {
    stop: Arc<AtomicBool>,
    thread: Option<JoinHandle<()>>,
}

impl ServicesHandle {
    /// Stops the tasks and joins the executor thread.
    pub fn stop(mut self) {
        self.shutdown();
    }

    fn shutdown(&mut self) {
        self.stop.store(true, Ordering::Release);
        if let Some(t) = self.thread.take() {
            let _ = t.join();
        }
    }
}

impl Drop for ServicesHandle {
    fn drop(&mut self) {
        self.shutdown();
    }
}

/// Why the services could not start.
#[derive(Debug, thiserror::Error)]
pub enum SpawnError {
    /// The executor thread could not be created.
    #[error("cannot start the services thread: {0}")]
    Thread(#[from] std::io::Error),
}

/// What the tasks share on the executor thread.
struct Shared {
    stop: Arc<AtomicBool>,
    live: Arc<AtomicUsize>,
    sink: RefCell<Sink>,
    /// The cycle's fault events, for the boot task's lifecycle (lost drives).
    faults: RefCell<Vec<Event>>,
}

impl Shared {
    fn report(&self, e: ServiceEvent) {
        if let Ok(mut s) = self.sink.try_borrow_mut() {
            s(e);
        }
    }
    fn stopping(&self) -> bool {
        self.stop.load(Ordering::Acquire)
    }
}

/// Decrements the live-task count when a task ends (also if it panics).
struct Alive(Arc<AtomicUsize>);
impl Drop for Alive {
    fn drop(&mut self) {
        self.0.fetch_sub(1, Ordering::AcqRel);
    }
}

async fn tick(d: Duration) {
    embassy_time::Timer::after(embassy_time::Duration::from_micros(d.as_micros() as u64)).await;
}

/// Tasks of one services instance; a pool of 4 lets tests run a few machines side by side.
#[embassy_executor::task(pool_size = 4)]
async fn boot_task(
    shared: Rc<Shared>,
    mut nodes: Nodes,
    mut tx: Producer<'static, BusFrame>,
    mut rx: Consumer<'static, BusFrame>,
    mut reports: Producer<'static, QueuedReport>,
) {
    let _alive = Alive(shared.live.clone());
    let mut held: Option<BusFrame> = None;
    let mut queued = 0u64;
    let mut waiting: Option<NodeReport> = None;
    let mut finished_told = false;
    while !shared.stopping() {
        let now = monotonic_now();
        while let Some(f) = rx.dequeue() {
            if let Some(code) = emcy_of(&f.frame) {
                shared.report(code);
            }
            nodes.handle_frame(&f, now);
        }
        for e in shared.faults.borrow_mut().drain(..) {
            nodes.event(&e);
        }
        if nodes.poll_timeout().is_some_and(|t| t <= now) {
            nodes.handle_timeout(now);
        }
        // Out to the cycle; a frame the queue cannot take waits for the next tick.
        while let Some(f) = held.take().or_else(|| nodes.poll_transmit(now)) {
            if let Err(f) = tx.enqueue(f) {
                held = Some(f);
                break;
            }
            queued += 1;
        }
        // Every frame handed out so far, the held one included.
        let after_frames = queued + u64::from(held.is_some());
        while let Some(r) = waiting.take().or_else(|| nodes.poll_report()) {
            let q = QueuedReport {
                report: r,
                after_frames,
            };
            if reports.enqueue(q).is_err() {
                waiting = Some(r);
                break;
            }
            shared.report(ServiceEvent::Node(r));
        }
        if !finished_told && nodes.is_finished() && waiting.is_none() {
            finished_told = true;
            shared.report(ServiceEvent::BootFinished);
        }
        let wait = nodes
            .poll_timeout()
            .map(|t| t.saturating_duration_since(monotonic_now()))
            .map_or(SERVICE_TICK, |d| d.min(SERVICE_TICK));
        tick(wait).await;
    }
}

/// An EMCY (80h + n, 8 bytes: a boot-up on that identifier has 0 or 1) as a service event.
fn emcy_of(f: &Frame) -> Option<ServiceEvent> {
    let id = f.cob_id()?;
    if id & !0x7F != ids::EMCY || id & 0x7F == 0 || f.dlc() != 8 {
        return None;
    }
    let d = f.data8();
    Some(ServiceEvent::Emcy {
        node: (id & 0x7F) as u8,
        code: u16::from_le_bytes([d[0], d[1]]),
        register: d[2],
    })
}

#[embassy_executor::task(pool_size = 4)]
async fn event_task(shared: Rc<Shared>, mut events: Consumer<'static, Event>) {
    let _alive = Alive(shared.live.clone());
    while !shared.stopping() {
        while let Some(e) = events.dequeue() {
            if matches!(e, Event::Fault { .. }) {
                shared.faults.borrow_mut().push(e);
            }
            shared.report(ServiceEvent::Cycle(e));
        }
        tick(SERVICE_TICK).await;
    }
}

/// Starts the services' executor thread with the boot, command and event tasks; `sink` gets
/// every report. At most 4 instances may run at once (the static task pools).
pub fn spawn_services(
    ends: ServiceEnds,
    nodes: Nodes,
    sink: Sink,
) -> Result<ServicesHandle, SpawnError> {
    let stop = Arc::new(AtomicBool::new(false));
    let live = Arc::new(AtomicUsize::new(0));
    let stop2 = stop.clone();
    let thread = std::thread::Builder::new()
        .name("services".into())
        .spawn(move || run_executor(ends, nodes, sink, stop2, live))?;
    Ok(ServicesHandle {
        stop,
        thread: Some(thread),
    })
}

fn run_executor(
    ends: ServiceEnds,
    nodes: Nodes,
    sink: Sink,
    stop: Arc<AtomicBool>,
    live: Arc<AtomicUsize>,
) {
    let shared = Rc::new(Shared {
        stop: stop.clone(),
        live: live.clone(),
        sink: RefCell::new(sink),
        faults: RefCell::new(Vec::new()),
    });
    // The executor must be 'static; one small leak per services instance.
    let executor: &'static mut embassy_executor::Executor =
        Box::leak(Box::new(embassy_executor::Executor::new()));
    let ServiceEnds {
        events,
        tx_frames,
        rx_frames,
        boot_reports,
    } = ends;
    let live_done = live.clone();
    executor.run_until(
        |spawner| {
            // A full task pool (more than 4 instances) stops the others again.
            fn go<S>(
                spawner: embassy_executor::Spawner,
                t: Result<embassy_executor::SpawnToken<S>, embassy_executor::SpawnError>,
                live: &AtomicUsize,
                stop: &AtomicBool,
            ) {
                match t {
                    Ok(t) => {
                        live.fetch_add(1, Ordering::AcqRel);
                        spawner.spawn(t);
                    }
                    Err(_) => stop.store(true, Ordering::Release),
                }
            }
            let t = boot_task(shared.clone(), nodes, tx_frames, rx_frames, boot_reports);
            go(spawner, t, &live, &stop);
            go(spawner, event_task(shared, events), &live, &stop);
        },
        // Every task has seen the stop flag and ended, so its pool slot is free again.
        move || live_done.load(Ordering::Acquire) == 0,
    );
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::command::{Reply, Target};

    fn frame(id: u16) -> Frame {
        Frame::std8(id, [0; 8])
    }

    #[test]
    fn the_cycle_forwards_only_service_frames() {
        for id in [0x583, 0x703, 0x083, 0x0FF] {
            assert!(is_service_frame(&frame(id)), "{id:03X}h");
        }
        for id in [0x000, 0x080, 0x183, 0x203, 0x603, 0x700] {
            assert!(!is_service_frame(&frame(id)), "{id:03X}h");
        }
    }

    #[test]
    fn full_queues_return_errors() {
        let (mut cycle, _service, mut port) = channels();
        let on = |id| BusFrame::new(0, frame(id));
        assert_eq!(cycle.offer_received(&on(0x183)), Ok(false));
        for _ in 0..RX_FRAMES {
            assert_eq!(cycle.offer_received(&on(0x583)), Ok(true));
        }
        assert_eq!(
            cycle.offer_received(&on(0x583)),
            Err(QueueFull {
                queue: "received frames",
                capacity: RX_FRAMES
            })
        );
        let a = Answer {
            tag: 1,
            reply: Reply::Latched { cycle: 1 },
        };
        for _ in 0..ANSWERS {
            cycle.answer(a).unwrap();
        }
        assert!(cycle.answer(a).is_err());
        let e = Event::Acknowledged { cycle: 1, axis: 0 };
        for _ in 0..EVENTS {
            cycle.event(e).unwrap();
        }
        assert!(cycle.event(e).is_err());
        let stop = Command::Stop(Target::All);
        for _ in 0..REQUESTS {
            port.submit(stop).unwrap();
        }
        assert!(port.submit(stop).is_err());
        // The answers queue is full: the cycle takes no request (its answer would be lost).
        assert!(cycle.request().is_none());
        // A client takes an answer: one request may be taken, and its answer fits.
        assert_eq!(port.answer(), Some(a));
        let r = cycle.request().expect("room for one answer");
        assert_eq!(r.command, stop);
        cycle.answer(a).unwrap();
        assert!(cycle.request().is_none());
        // Taking one made room for one.
        assert!(port.submit(stop).is_ok());
    }

    #[test]
    fn a_boot_report_waits_for_the_frames_queued_before_it() {
        let (mut cycle, mut service, _port) = channels();
        let report = NodeReport {
            axis: 2,
            bus: 0,
            report: crate::runtime::boot::BootReport {
                node: drivers::canopen::NodeId::new(3).unwrap(),
                result: Ok(()),
                device_type: None,
                vendor_id: None,
            },
        };
        // Two SDO requests of other nodes, then this node's NMT start, then its report.
        for id in [0x601, 0x602, 0x000] {
            service
                .tx_frames
                .enqueue(BusFrame::new(0, frame(id)))
                .unwrap();
        }
        service
            .boot_reports
            .enqueue(QueuedReport {
                report,
                after_frames: 3,
            })
            .unwrap();
        // The cycle sends two frames per cycle: the node is not online before its NMT start
        // went out.
        let id = |f: Option<BusFrame>| f.map(|f| f.frame.raw_id());
        assert_eq!(cycle.boot_report(), None);
        assert_eq!(id(cycle.tx_frame()), Some(0x601));
        assert_eq!(id(cycle.tx_frame()), Some(0x602));
        assert_eq!(cycle.boot_report(), None);
        assert_eq!(id(cycle.tx_frame()), Some(0x000));
        assert_eq!(cycle.boot_report(), Some(report));
        assert_eq!(cycle.boot_report(), None);
    }

    #[test]
    fn the_command_port_tags_requests_and_refuses_what_the_cycle_cannot_take() {
        let (mut cycle, _service, mut port) = channels();
        // The cycle takes nothing yet: REQUESTS fit its queue, the next is refused at once.
        let tags: Vec<u64> = (0..REQUESTS)
            .map(|_| port.submit(Command::Stop(Target::All)).unwrap())
            .collect();
        assert_eq!(tags, (1..=REQUESTS as u64).collect::<Vec<_>>());
        assert!(port.submit(Command::Stop(Target::All)).is_err());
        // The cycle answers each with its tag; the port hands the answers back in order.
        while let Some(r) = cycle.requests.dequeue() {
            cycle
                .answer(Answer {
                    tag: r.tag,
                    reply: Reply::Latched { cycle: r.tag * 10 },
                })
                .unwrap();
        }
        for &t in &tags {
            assert_eq!(
                port.answer(),
                Some(Answer {
                    tag: t,
                    reply: Reply::Latched { cycle: t * 10 }
                })
            );
        }
        assert_eq!(port.answer(), None);
        // Room again, and the tags go on.
        assert_eq!(
            port.submit(Command::Stop(Target::All)).unwrap(),
            REQUESTS as u64 + 1
        );
    }
}
