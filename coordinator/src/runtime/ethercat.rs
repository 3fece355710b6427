//! An EtherCAT bus's exchange, on its own thread: ethercrab is the master on a raw socket of
//! the bus's interface, and the cycle thread never touches the socket.
//!
//! [`spawn`] opens the interface and starts the thread; it returns the [`SegmentCycleSide`] the
//! cycle thread uses. Each cycle the cycle thread [`put`](SegmentCycleSide::put)s every
//! subdevice's 8 output bytes, [`send`](SegmentCycleSide::send)s them as one set (one
//! triple-buffer publish and an unpark: the thread sends the frame at once, so every axis of a
//! group latches from the same frame, in the cycle that computed it) and
//! [`take`](SegmentCycleSide::take)s each subdevice's latest inputs with its state. None of this
//! allocates or locks.
//!
//! The thread:
//! - boots the segment as seed-002 §5.2 and the EtherCAT digest describe: scan
//!   (ethercrab's `init_single_group`: addresses, SII, mailboxes, DC delays and offsets,
//!   Pre-Operational), the identity of every subdevice against the device catalog (vendor,
//!   product, revision), 1C32h:05 and 1C33h:05 (the shortest cycle) against the configured
//!   cycle, the mappings of the assigned PDOs against the catalog's, the PDO assignment
//!   1C12h/1C13h written over CoE and read back, DC SYNC0 mode (1C32h:01 = 2) and the drive's
//!   parameters, SYNC0 at the cycle's period, Safe-Operational with valid outputs, then
//!   Operational;
//! - exchanges one frame per cycle (ethercrab's `tx_rx_dc`: the reference clock's time to the
//!   others, an LRW of the whole process image and every subdevice's AL status), as soon as
//!   the cycle thread hands the outputs over, or after a whole period without them (the
//!   subdevices' SM watchdog stays fed while the cycle is not running yet);
//! - publishes each subdevice's inputs and state: in Op, not in Op (its AL state), or lost (its
//!   AL status read did not come back: switched off, or the line is broken before it; or, with
//!   all in Op, the LRW's working counter is not 3 per subdevice);
//! - brings a lost or fallen-back subdevice back to Op by itself, beside the others'
//!   exchange: its station address again (a power cycle clears it), its mailbox sync managers,
//!   Pre-Operational, the PDO assignment and parameters, its clock and SYNC0, its process-data
//!   sync managers and FMMUs as ethercrab set them at boot, Safe-Operational, Operational; a
//!   subdevice that kept its configuration only has its error acknowledged and is asked for Op
//!   again. Its axis stays faulted until the operator acknowledges;
//! - reads each subdevice's emergencies (CoE EMCY) from its input mailbox (SM1) every
//!   [`EMCY_POLL_CYCLES`] cycles: ethercrab reads mailboxes only when it asked something;
//! - measures each cyclic frame's round trip ([`SegmentStats`], in the run's summary);
//! - with `--capture`, writes every frame sent and received to a pcap file (link type Ethernet,
//!   which Wireshark decodes as EtherCAT), in Unix time as the CAN captures.

use std::future::Future;
use std::pin::{Pin, pin};
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::sync::mpsc::Sender;
use std::task::{Context, Poll, Waker};
use std::thread::{self, JoinHandle, Thread};
use std::time::Duration;

use drivers::catalog::EthercatFacts;
use drivers::ethercat::coe;
use drivers::ethercat::esm::AlState;
use drivers::ethercat::frame::MAX_FRAME_LEN;
use drivers::ethercat::pcap::EcPcapWriter;
use drivers::ethercat::raw::RawSocket;
use drivers::ethercat::register as reg;
use drivers::time::monotonic_now;
use ethercrab::error::Error;
use ethercrab::std::ethercat_now;
use ethercrab::{
    Command, MainDevice, MainDeviceConfig, PduRx, PduStorage, PduTx, SubDeviceGroup,
    SubDeviceState, Timeouts, subdevice_group,
};
use handover::triple_buffer::{TripleReader, TripleWriter, triple_buffer};

use crate::cycle::ImageInput;

/// Subdevices one bus holds at most (`config::MAX_SUBDEVICES`).
pub const MAX_SUBDEVICES: usize = crate::config::MAX_SUBDEVICES;
/// The process image ethercrab's group holds: 8 bytes in and 8 out per subdevice.
const PDI_LEN: usize = MAX_SUBDEVICES * 16;
/// Frames in flight at once (the cycle's and a recovery's).
const MAX_FRAMES: usize = 16;
/// The EMCA's vendor ID, the catalog's (1018h:01, SII word 08h).
const FESTO_VENDOR: u32 = 0x0000_001D;
/// Cycles between two looks at the subdevices' input mailboxes for emergencies.
pub const EMCY_POLL_CYCLES: u64 = 10;
/// How long a recovery step waits for a subdevice to reach a state it was asked for.
const STATE_TIMEOUT: Duration = Duration::from_secs(2);

type Group<S, DC = subdevice_group::NoDc> =
    SubDeviceGroup<MAX_SUBDEVICES, PDI_LEN, ethercrab::DefaultLock, S, DC>;
/// The group in Op with SYNC0 running.
type OpGroup = Group<subdevice_group::Op, subdevice_group::HasDc>;
/// How long after the start-up the first SYNC0 pulse comes.
const SYNC0_START_DELAY: Duration = Duration::from_millis(100);

/// A subdevice's state as the cycle sees it.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum SubState {
    /// Not booted yet (the segment is being scanned or configured).
    Booting,
    /// In Op; its inputs are valid.
    Op,
    /// It answers but is not in Op: its AL state.
    NotOp(AlState),
    /// Its AL status read did not come back.
    Lost,
    /// Refused at boot (wrong device, a cycle it cannot run, an assignment it did not take).
    Refused,
}

/// The outputs the cycle hands over.
#[derive(Clone, Copy, Debug)]
struct Outputs {
    cycle: u64,
    images: [[u8; 8]; MAX_SUBDEVICES],
}

/// What the thread publishes after every exchange.
#[derive(Clone, Copy, Debug)]
struct Published {
    /// Exchanges completed so far.
    exchanges: u64,
    inputs: [[u8; 8]; MAX_SUBDEVICES],
    states: [SubState; MAX_SUBDEVICES],
    /// Per subdevice: emergencies read so far, and the last one's error code.
    emcy: [(u32, u16); MAX_SUBDEVICES],
}

/// What a bus's thread tells the operator.
#[derive(Clone, Debug, PartialEq, Eq)]
pub enum SegmentReport {
    /// A line to print as it is (it names the bus).
    Line(String),
    /// The segment was refused at boot (a boot failure of every axis on it): the bus and why.
    Refused {
        /// The bus's name.
        bus: String,
        /// Why, in words.
        why: String,
    },
}

/// How the thread runs.
#[derive(Clone, Debug)]
pub struct SegmentSettings {
    /// The bus's name, for messages.
    pub name: String,
    /// The cycle period.
    pub period: Duration,
    /// What each subdevice must be, position 1 first.
    pub devices: Vec<&'static EthercatFacts>,
    /// Per subdevice: the objects written over CoE after the PDO assignment, at boot and
    /// after a power cycle (address, value, size in bytes).
    pub parameters: Vec<Vec<(drivers::canopen::Address, u32, u8)>>,
    /// `--capture`: the pcap file to write every frame to.
    pub capture: Option<std::path::PathBuf>,
}

/// The cycle thread's end: no lock, no allocation in any method; [`send`](Self::send) makes
/// one futex call (the unpark) when the thread is asleep.
pub struct SegmentCycleSide {
    output: TripleWriter<Outputs>,
    input: TripleReader<Published>,
    pending: Outputs,
    latest: Published,
    read_in: Option<u64>,
    exchanges_seen: u64,
    fresh: bool,
    /// Cycles since the last exchange completed.
    stale: u32,
    emcy_seen: [u32; MAX_SUBDEVICES],
    /// Per subdevice: the state last reported as a node report (Op or Refused), for
    /// [`SegmentCycleSide::report`].
    reported: [Option<bool>; MAX_SUBDEVICES],
    len: usize,
    /// Cycles without an exchange before every subdevice counts as lost ([`STALE`]).
    stale_limit: u32,
    /// The bus's thread, woken by [`SegmentCycleSide::send`].
    thread: Option<Thread>,
}

impl std::fmt::Debug for SegmentCycleSide {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("SegmentCycleSide")
            .field("subdevices", &self.len)
            .finish_non_exhaustive()
    }
}

/// Without a completed exchange for this long (and at least three cycles), every subdevice
/// counts as lost: the frames stopped coming back, or the thread is stalled. Long enough that
/// a busy host's scheduling does not pass for a broken line; well inside the subdevices' SM
/// watchdog (100 ms).
const STALE: Duration = Duration::from_millis(30);

impl SegmentCycleSide {
    /// Subdevice `i`'s (0 first) output image for this cycle.
    pub fn put(&mut self, i: usize, image: &[u8; 8]) {
        if let Some(o) = self.pending.images.get_mut(i) {
            *o = *image;
        }
    }

    /// The thread [`send`](Self::send) wakes (the bus's: [`spawn`] sets it).
    pub fn wake(&mut self, thread: Thread) {
        self.thread = Some(thread);
    }

    /// Hands this cycle's outputs over, all at once, and wakes the thread to send them.
    pub fn send(&mut self, cycle: u64) {
        self.pending.cycle = cycle;
        self.output.publish(self.pending);
        if let Some(t) = &self.thread {
            t.unpark();
        }
    }

    fn read(&mut self, cycle: u64) {
        if self.read_in == Some(cycle) {
            return;
        }
        self.read_in = Some(cycle);
        let (p, _) = self.input.read();
        self.latest = p;
        self.fresh = p.exchanges != self.exchanges_seen;
        self.exchanges_seen = p.exchanges;
        self.stale = if self.fresh {
            0
        } else {
            self.stale.saturating_add(1)
        };
    }

    /// Subdevice `i`'s inputs and state as of `cycle`.
    pub fn take(&mut self, cycle: u64, i: usize) -> ImageInput {
        self.read(cycle);
        let Some(&state) = self.latest.states.get(i) else {
            return ImageInput::default();
        };
        let (seq, code) = self.latest.emcy[i];
        let emcy = if seq != self.emcy_seen[i] {
            self.emcy_seen[i] = seq;
            code
        } else {
            0
        };
        let stalled = self.stale >= self.stale_limit;
        ImageInput {
            image: crate::axis::Image::from_slice(&self.latest.inputs[i]).unwrap_or_default(),
            fresh: self.fresh && state == SubState::Op,
            late_cycles: 0,
            lost: state == SubState::Lost || (stalled && state == SubState::Op),
            not_op: match state {
                SubState::NotOp(s) => s as u8,
                _ => 0,
            },
            emcy,
        }
    }

    /// The next change worth a node report: `(i, true)` when subdevice `i` first reached Op,
    /// `(i, false)` when it was refused.
    pub fn report(&mut self) -> Option<(usize, bool)> {
        for i in 0..self.len {
            let now = match self.latest.states[i] {
                SubState::Op => Some(true),
                SubState::Refused => Some(false),
                _ => None,
            };
            if now.is_some() && self.reported[i].is_none() {
                self.reported[i] = now;
                return Some((i, now == Some(true)));
            }
        }
        None
    }
}

/// What a bus's thread did, for the run's summary.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct SegmentStats {
    /// Frames written to the capture.
    pub captured: u64,
    /// Cyclic exchanges completed.
    pub exchanges: u64,
    /// The cyclic frame's round trip as the thread sees it (sent to answered, through the
    /// socket and the subdevices): median, p99, max, ns.
    pub round_trip_ns: (u64, u64, u64),
}

impl std::fmt::Display for SegmentStats {
    /// `frame round trip median 110.2 us, p99 175.1 us, max 461.1 us over 4000 cycles`.
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        let us = |ns: u64| ns as f64 / 1000.0;
        let (p50, p99, max) = self.round_trip_ns;
        if self.exchanges == 0 {
            return f.write_str("no cyclic exchange");
        }
        write!(
            f,
            "frame round trip median {:.1} us, p99 {:.1} us, max {:.1} us over {} cycles",
            us(p50),
            us(p99),
            us(max),
            self.exchanges
        )
    }
}

/// The running thread; dropping it stops the thread too.
#[derive(Debug)]
pub struct SegmentThread {
    stop: Arc<AtomicBool>,
    handle: Option<JoinHandle<SegmentStats>>,
    captured: Arc<AtomicU64>,
}

impl SegmentThread {
    /// Stops the thread and waits for it (the subdevices stay in Op until their watchdog
    /// expires, as when a master stops on a real line). Returns what it did.
    pub fn stop(mut self) -> SegmentStats {
        let mut s = self.stop_and_join();
        s.captured = self.captured.load(Ordering::Relaxed);
        s
    }

    fn stop_and_join(&mut self) -> SegmentStats {
        self.stop.store(true, Ordering::Relaxed);
        match self.handle.take() {
            Some(h) => {
                h.thread().unpark();
                h.join().unwrap_or_default()
            }
            None => SegmentStats::default(),
        }
    }
}

impl Drop for SegmentThread {
    fn drop(&mut self) {
        let _ = self.stop_and_join();
    }
}

/// Opens `interface` and starts the thread. Fails when the interface cannot be opened (no such
/// interface, no permission for raw sockets: the message names the interface and the reason)
/// or the thread cannot be started. `lines` gets what the thread has to tell the operator.
pub fn spawn(
    interface: &str,
    settings: SegmentSettings,
    lines: Sender<SegmentReport>,
) -> Result<(SegmentCycleSide, SegmentThread), String> {
    let mut pump = Pump::open(interface)?;
    pump.capture = match &settings.capture {
        Some(path) => Some(
            std::fs::File::create(path)
                .and_then(|f| EcPcapWriter::new(std::io::BufWriter::new(f)))
                .map_err(|e| format!("--capture {}: {e}", path.display()))?,
        ),
        None => None,
    };
    let (mut side, feed) = hand_over(settings.devices.len(), settings.period);
    let stop = Arc::new(AtomicBool::new(false));
    let stop2 = stop.clone();
    let captured = pump.captured.clone();
    let handle = thread::Builder::new()
        .name(format!("ethercat-{interface}"))
        .spawn(move || {
            let mut t = SegmentRun::new(pump, settings, stop2, feed, lines);
            t.run();
            let h = &t.round_trip;
            SegmentStats {
                captured: 0,
                exchanges: h.len(),
                round_trip_ns: (h.value_at_quantile(0.5), h.value_at_quantile(0.99), h.max()),
            }
        })
        .map_err(|e| format!("starting the EtherCAT thread: {e}"))?;
    side.wake(handle.thread().clone());
    Ok((
        side,
        SegmentThread {
            stop,
            handle: Some(handle),
            captured,
        },
    ))
}

/// The hand-over between the cycle thread and a bus's thread, for `len` subdevices at
/// `period`: the cycle's side, and the feed the bus's thread (or a test) takes the outputs from
/// and publishes the inputs through. [`spawn`] makes one for its thread; alone, its cycle side
/// wakes nobody.
pub fn hand_over(len: usize, period: Duration) -> (SegmentCycleSide, SegmentFeed) {
    let len = len.min(MAX_SUBDEVICES);
    let (out_w, out_r) = triple_buffer(Outputs {
        cycle: 0,
        images: [[0; 8]; MAX_SUBDEVICES],
    });
    let initial = Published {
        exchanges: 0,
        inputs: [[0; 8]; MAX_SUBDEVICES],
        states: [SubState::Booting; MAX_SUBDEVICES],
        emcy: [(0, 0); MAX_SUBDEVICES],
    };
    let (in_w, in_r) = triple_buffer(initial);
    (
        SegmentCycleSide {
            output: out_w,
            input: in_r,
            pending: Outputs {
                cycle: 0,
                images: [[0; 8]; MAX_SUBDEVICES],
            },
            latest: initial,
            read_in: None,
            exchanges_seen: 0,
            fresh: false,
            stale: 0,
            emcy_seen: [0; MAX_SUBDEVICES],
            reported: [None; MAX_SUBDEVICES],
            len,
            stale_limit: (STALE.as_nanos() / period.as_nanos().max(1)).max(3) as u32,
            thread: None,
        },
        SegmentFeed {
            output: out_r,
            input: in_w,
            published: initial,
        },
    )
}

/// The bus thread's end of [`hand_over`].
pub struct SegmentFeed {
    output: TripleReader<Outputs>,
    input: TripleWriter<Published>,
    published: Published,
}

impl std::fmt::Debug for SegmentFeed {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("SegmentFeed")
            .field("exchanges", &self.published.exchanges)
            .finish_non_exhaustive()
    }
}

impl SegmentFeed {
    /// The outputs the cycle handed over last, if new since the last call: the cycle that
    /// computed them and every subdevice's 8 bytes.
    pub fn outputs(&mut self) -> Option<(u64, [[u8; 8]; MAX_SUBDEVICES])> {
        let (o, fresh) = self.output.read();
        fresh.then_some((o.cycle, o.images))
    }

    /// Publishes one exchange: each subdevice's state and inputs (position 1 first), and the
    /// emergencies it read, as (subdevice index, error code).
    pub fn publish(&mut self, states: &[SubState], inputs: &[[u8; 8]], emcy: &[(usize, u16)]) {
        let p = &mut self.published;
        p.exchanges += 1;
        for (s, v) in p.states.iter_mut().zip(states) {
            *s = *v;
        }
        for (i, v) in p.inputs.iter_mut().zip(inputs) {
            *i = *v;
        }
        for &(i, code) in emcy {
            if let Some(e) = p.emcy.get_mut(i) {
                *e = (e.0.wrapping_add(1), code);
            }
        }
        self.input.publish(*p);
    }
}

/// ethercrab's master on a raw socket, its frames pumped by the calling thread (no executor):
/// futures are polled with a no-op waker, and between polls the pump sends what ethercrab
/// queued and hands back what came in. A bus's thread runs one; [`Pump::open`] gives one to
/// any other master (the EtherCAT tests drive ethercrab by hand with it).
pub struct Pump {
    md: &'static MainDevice<'static>,
    tx: PduTx<'static>,
    rx: PduRx<'static>,
    sock: RawSocket,
    capture: Option<EcPcapWriter<std::io::BufWriter<std::fs::File>>>,
    /// Frames written to the capture.
    captured: Arc<AtomicU64>,
    /// Added to the monotonic clock to give Unix time in the capture, as the CAN captures do
    /// (so that the buses' files line up).
    epoch_offset: u64,
    buf: Box<[u8; MAX_FRAME_LEN]>,
}

impl std::fmt::Debug for Pump {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Pump")
            .field("interface", &self.sock.interface())
            .finish_non_exhaustive()
    }
}

impl Pump {
    /// A master on `interface` (raw sockets need CAP_NET_RAW), without a capture. Its
    /// ethercrab storage lives as long as the process.
    pub fn open(interface: &str) -> Result<Pump, String> {
        let sock = RawSocket::open(interface).map_err(|e| e.to_string())?;
        Ok(Pump::new(sock))
    }

    /// ethercrab's main device, to build the futures [`Pump::block`] runs.
    pub fn main_device(&self) -> &'static MainDevice<'static> {
        self.md
    }

    fn new(sock: RawSocket) -> Pump {
        const DATA: usize = PduStorage::element_size(1100);
        // Once per segment per run: ethercrab's master borrows its storage for its life.
        let storage: &'static PduStorage<MAX_FRAMES, DATA> = Box::leak(Box::new(PduStorage::new()));
        let (tx, rx, pdu_loop) = storage
            .try_split()
            .unwrap_or_else(|_| unreachable!("fresh storage splits once"));
        let md = Box::leak(Box::new(MainDevice::new(
            pdu_loop,
            Timeouts {
                pdu: Duration::from_millis(20),
                state_transition: STATE_TIMEOUT,
                ..Timeouts::default()
            },
            MainDeviceConfig {
                dc_static_sync_iterations: 0,
                ..MainDeviceConfig::default()
            },
        )));
        Pump {
            md,
            tx,
            rx,
            sock,
            capture: None,
            captured: Arc::new(AtomicU64::new(0)),
            epoch_offset: std::time::SystemTime::now()
                .duration_since(std::time::UNIX_EPOCH)
                .map_or(0, |d| u64::try_from(d.as_nanos()).unwrap_or(u64::MAX))
                .saturating_sub(monotonic_now().as_nanos()),
            buf: Box::new([0; MAX_FRAME_LEN]),
        }
    }

    /// Sends what ethercrab queued and takes in what arrived, waiting up to `wait` for the
    /// first frame.
    fn pump(&mut self, wait: Duration) -> Result<(), String> {
        while let Some(frame) = self.tx.next_sendable_frame() {
            let (sock, capture, captured) = (&self.sock, &mut self.capture, &self.captured);
            let offset = self.epoch_offset;
            frame
                .send_blocking(|b| {
                    sock.send(b).map_err(|_| Error::SendFrame)?;
                    if let Some(c) = capture
                        && c.write(epoch(offset), b).is_ok()
                    {
                        captured.fetch_add(1, Ordering::Relaxed);
                    }
                    Ok(b.len())
                })
                .map_err(|e| format!("sending on {}: {e}", self.sock.interface()))?;
        }
        let mut wait = wait;
        while let Some(n) = self
            .sock
            .recv(&mut self.buf, wait)
            .map_err(|e| format!("receiving on {}: {e}", self.sock.interface()))?
        {
            if let Some(c) = &mut self.capture
                && c.write(epoch(self.epoch_offset), &self.buf[..n]).is_ok()
            {
                self.captured.fetch_add(1, Ordering::Relaxed);
            }
            // A frame ethercrab gave up on (timed out) is refused; it changes nothing.
            let _ = self.rx.receive_frame(&self.buf[..n]);
            wait = Duration::ZERO;
        }
        Ok(())
    }

    /// Runs `fut` to its end; `side`, if any, is polled alongside (a recovery beside the
    /// cycle's exchange) and dropped to `None` when it ends.
    fn run<T>(
        &mut self,
        fut: impl Future<Output = T>,
        side: &mut Option<Pin<Box<dyn Future<Output = Recovered> + '_>>>,
        side_done: &mut Option<Recovered>,
    ) -> Result<T, String> {
        let mut fut = pin!(fut);
        let mut cx = Context::from_waker(Waker::noop());
        loop {
            if let Poll::Ready(r) = fut.as_mut().poll(&mut cx) {
                return Ok(r);
            }
            if let Some(s) = side
                && let Poll::Ready(r) = s.as_mut().poll(&mut cx)
            {
                *side = None;
                *side_done = Some(r);
            }
            self.pump(Duration::from_micros(50))?;
        }
    }

    /// Runs `fut` to its end alone; fails only when the socket does.
    pub fn block<T>(&mut self, fut: impl Future<Output = T>) -> Result<T, String> {
        let mut fut = pin!(fut);
        let mut cx = Context::from_waker(Waker::noop());
        loop {
            if let Poll::Ready(r) = fut.as_mut().poll(&mut cx) {
                return Ok(r);
            }
            self.pump(Duration::from_micros(200))?;
        }
    }
}

/// Now, in Unix time.
fn epoch(offset: u64) -> drivers::time::Instant {
    drivers::time::Instant::from_nanos(monotonic_now().as_nanos().saturating_add(offset))
}

/// What one recovery attempt ended with.
#[derive(Debug)]
struct Recovered {
    index: usize,
    result: Result<(), String>,
}

/// How ethercrab configured one subdevice at boot: its sync managers and FMMUs, written back
/// to it after a power cycle.
#[derive(Clone, Copy, Debug)]
struct EscSetup {
    address: u16,
    sm: [u8; 32],
    fmmu: [u8; 48],
    /// Its DC propagation delay (0928h), as the scan measured it.
    dc_delay: u32,
}

impl EscSetup {
    const EMPTY: EscSetup = EscSetup {
        address: 0,
        sm: [0; 32],
        fmmu: [0; 48],
        dc_delay: 0,
    };
}

/// What a subdevice's clock and SYNC0 are set from after a power cycle.
#[derive(Clone, Copy, Debug)]
struct DcRestore {
    /// The reference clock's station address.
    reference: u16,
    /// SYNC0's period (the cycle).
    period: Duration,
    /// The system time the last frame read, and when.
    clock: Option<(u64, drivers::time::Instant)>,
}

/// 1C32h:04: the subdevice offers DC SYNC0.
const SYNC_DC: u16 = 0x0004;

struct SegmentRun {
    pump: Pump,
    settings: SegmentSettings,
    stop: Arc<AtomicBool>,
    feed: SegmentFeed,
    lines: Sender<SegmentReport>,
    /// The cyclic frame's round trip, ns (allocated once, before the cycle).
    round_trip: hdrhistogram::Histogram<u64>,
}

/// Why the boot stopped.
enum BootEnd {
    /// Try again later (fewer subdevices than configured, a frame lost): the reason.
    Retry(String),
    /// Wrong segment: every subdevice refused, the reason.
    Refused(String),
    /// The socket failed.
    Fatal(String),
}

impl SegmentRun {
    fn new(
        pump: Pump,
        settings: SegmentSettings,
        stop: Arc<AtomicBool>,
        feed: SegmentFeed,
        lines: Sender<SegmentReport>,
    ) -> SegmentRun {
        SegmentRun {
            pump,
            settings,
            stop,
            feed,
            lines,
            round_trip: hdrhistogram::Histogram::new_with_bounds(1, 10_000_000_000, 3)
                .unwrap_or_else(|_| unreachable!("valid bounds")),
        }
    }

    fn say(&self, text: String) {
        let _ = self.lines.send(SegmentReport::Line(format!(
            "EtherCAT bus {}: {text}",
            self.settings.name
        )));
    }

    fn stopped(&self) -> bool {
        self.stop.load(Ordering::Relaxed)
    }

    fn run(&mut self) {
        let mut last_retry = String::new();
        while !self.stopped() {
            match self.boot() {
                Ok(()) => break,
                Err(BootEnd::Retry(why)) => {
                    if why != last_retry {
                        self.say(format!("{why}; trying again every 500 ms"));
                        last_retry = why;
                    }
                    // The cycle's hand-overs unpark this thread every cycle: sleep the
                    // whole 500 ms regardless.
                    let until = monotonic_now() + Duration::from_millis(500);
                    while !self.stopped() && monotonic_now() < until {
                        thread::park_timeout(until.saturating_duration_since(monotonic_now()));
                    }
                }
                Err(BootEnd::Refused(why)) => {
                    let _ = self.lines.send(SegmentReport::Refused {
                        bus: self.settings.name.clone(),
                        why,
                    });
                    let n = self.settings.devices.len();
                    self.feed.published.states[..n].fill(SubState::Refused);
                    self.feed.input.publish(self.feed.published);
                    while !self.stopped() {
                        thread::park_timeout(Duration::from_millis(100));
                    }
                    break;
                }
                Err(BootEnd::Fatal(why)) => {
                    self.say(format!("stopped: {why}"));
                    break;
                }
            }
        }
        if let Some(c) = &mut self.pump.capture {
            let _ = c.flush();
        }
    }

    /// Scan, check, configure, Op; then the cycle until the stop.
    fn boot(&mut self) -> Result<(), BootEnd> {
        let n = self.settings.devices.len();
        let md = self.pump.md;
        let group: Group<subdevice_group::PreOp> = self
            .pump
            .block(md.init_single_group::<MAX_SUBDEVICES, PDI_LEN>(ethercat_now))
            .map_err(BootEnd::Fatal)?
            .map_err(|e| BootEnd::Retry(format!("scanning found no segment ({e})")))?;
        if group.len() != n {
            return Err(BootEnd::Retry(format!(
                "found {} subdevice(s), the configuration has {n}",
                group.len()
            )));
        }
        for (i, facts) in self.settings.devices.iter().enumerate() {
            let sd = group
                .subdevice(md, i)
                .map_err(|e| BootEnd::Retry(e.to_string()))?;
            let id = sd.identity();
            if (id.vendor_id, id.product_id, id.revision)
                != (FESTO_VENDOR, facts.product_code, facts.revision)
            {
                return Err(BootEnd::Refused(format!(
                    "subdevice {} is \"{}\" (vendor {:08X}h, product {:08X}h, revision {:08X}h); \
                     the configuration expects {} (vendor {FESTO_VENDOR:08X}h, product \
                     {:08X}h, revision {:08X}h)",
                    i + 1,
                    sd.name(),
                    id.vendor_id,
                    id.product_id,
                    id.revision,
                    facts.name,
                    facts.product_code,
                    facts.revision
                )));
            }
        }
        for i in 0..n {
            let sd = group
                .subdevice(md, i)
                .map_err(|e| BootEnd::Retry(e.to_string()))?;
            let facts = self.settings.devices[i];
            // The shortest cycle, outputs (1C32h:05) and inputs (1C33h:05).
            let mut min = 0u32;
            for index in [0x1C32u16, 0x1C33] {
                let m: u32 = self
                    .pump
                    .block(sd.sdo_read(index, 5))
                    .map_err(BootEnd::Fatal)?
                    .map_err(|e| {
                        BootEnd::Retry(format!("subdevice {}: {index:04X}h:05: {e}", i + 1))
                    })?;
                min = min.max(m);
            }
            let period_ns = self.settings.period.as_nanos() as u64;
            if u64::from(min) > period_ns {
                return Err(BootEnd::Refused(format!(
                    "the cycle of {} us is shorter than subdevice {}'s shortest, {} us \
                     (its 1C32h:05/1C33h:05)",
                    period_ns / 1000,
                    i + 1,
                    min / 1000
                )));
            }
            if !facts.dc || facts.sync_types & SYNC_DC == 0 {
                return Err(BootEnd::Refused(format!(
                    "subdevice {} ({}) has no distributed clock SYNC0, which the coordinator's \
                     EtherCAT buses use",
                    i + 1,
                    facts.name
                )));
            }
            let params = self.settings.parameters.get(i).map_or(&[][..], |p| &p[..]);
            let assign = self
                .pump
                .block(configure(&sd, facts, params))
                .map_err(BootEnd::Fatal)?;
            if let Err(e) = assign {
                return Err(BootEnd::Refused(format!("subdevice {}: {e}", i + 1)));
            }
        }
        // Distributed clocks: ethercrab's scan measured the delays and set every clock's
        // offset; SYNC0 at the cycle's period, each drive in DC mode (1C32h:01 = 2, written
        // with the parameters above).
        let mut group = group;
        for mut sd in group.iter_mut(md) {
            sd.set_dc_sync(ethercrab::DcSync::Sync0);
        }
        let group = self
            .pump
            .block(group.into_pre_op_pdi(md))
            .map_err(BootEnd::Fatal)?
            .map_err(|e| BootEnd::Retry(format!("the process data set-up failed ({e})")))?;
        let group = self
            .pump
            .block(group.configure_dc_sync(
                md,
                subdevice_group::DcConfiguration {
                    start_delay: SYNC0_START_DELAY,
                    sync0_period: self.settings.period,
                    sync0_shift: Duration::ZERO,
                },
            ))
            .map_err(BootEnd::Fatal)?
            .map_err(|e| BootEnd::Retry(format!("SYNC0 could not be set up ({e})")))?;
        let group = self
            .pump
            .block(group.into_safe_op(md))
            .map_err(BootEnd::Fatal)?
            .map_err(|e| BootEnd::Retry(format!("Safe-Operational refused ({e})")))?;
        // Valid outputs before Op (a subdevice refuses Op without them, AL status 0019h).
        for _ in 0..3 {
            self.write_outputs(&group);
            let _ = self
                .pump
                .block(group.tx_rx_dc(md))
                .map_err(BootEnd::Fatal)?;
        }
        let group = self
            .pump
            .block(group.request_into_op(md))
            .map_err(BootEnd::Fatal)?
            .map_err(|e| BootEnd::Retry(format!("Operational refused ({e})")))?;
        let deadline = monotonic_now() + STATE_TIMEOUT;
        loop {
            self.write_outputs(&group);
            let r = self
                .pump
                .block(group.tx_rx_dc(md))
                .map_err(BootEnd::Fatal)?;
            if r.as_ref().is_ok_and(|r| r.all_op()) {
                break;
            }
            if monotonic_now() > deadline {
                return Err(BootEnd::Retry(
                    "not every subdevice reached Operational within 2 s".into(),
                ));
            }
            thread::sleep(Duration::from_millis(1));
        }
        let mut setups = [EscSetup::EMPTY; MAX_SUBDEVICES];
        for (i, s) in setups.iter_mut().enumerate().take(n) {
            let sd = group
                .subdevice(md, i)
                .map_err(|e| BootEnd::Retry(e.to_string()))?;
            *s = self
                .pump
                .block(read_setup(md, sd.configured_address()))
                .map_err(BootEnd::Fatal)?
                .map_err(|e| BootEnd::Retry(format!("subdevice {}: {e}", i + 1)))?;
        }
        self.say(format!(
            "{n} subdevice(s) in Operational on {}",
            self.pump.sock.interface()
        ));
        self.cycle(&group, &setups).map_err(BootEnd::Fatal)
    }

    fn write_outputs<S>(&mut self, group: &Group<S, subdevice_group::HasDc>)
    where
        Group<S, subdevice_group::HasDc>: GroupIo,
    {
        let (o, _) = self.feed.output.read();
        group.write(self.pump.md, &o.images[..self.settings.devices.len()]);
    }

    /// The exchange, once per cycle, until the stop.
    fn cycle(
        &mut self,
        group: &OpGroup,
        setups: &[EscSetup; MAX_SUBDEVICES],
    ) -> Result<(), String> {
        let md = self.pump.md;
        let n = self.settings.devices.len();
        let mut last = monotonic_now();
        let mut exchanges = 0u64;
        let mut recovery: Option<Pin<Box<dyn Future<Output = Recovered> + '_>>> = None;
        let mut recovered: Option<Recovered> = None;
        let mut next_try = monotonic_now();
        let mut emcy_next = 0u64;
        let mut said_lost = [false; MAX_SUBDEVICES];
        let mut last_failure: Option<(usize, String)> = None;
        // The DC system time the last frame read, and when.
        let mut clock: Option<(u64, drivers::time::Instant)> = None;
        while !self.stopped() {
            // Sleep until the cycle hands its outputs over, or a whole period passed.
            let due = last + self.settings.period;
            let (o, fresh) = self.feed.output.read();
            let now = monotonic_now();
            if !fresh && now < due {
                thread::park_timeout(due.saturating_duration_since(now));
                continue;
            }
            last = now;
            group.write(md, &o.images[..n]);
            let sent = monotonic_now();
            let r = {
                let fut = group.tx_rx_dc(md);
                let mut side = recovery.take();
                let r = self.pump.run(fut, &mut side, &mut recovered);
                recovery = side;
                r?
            };
            if r.is_ok() {
                let ns = monotonic_now().saturating_duration_since(sent).as_nanos() as u64;
                let _ = self.round_trip.record(ns.max(1));
            }
            exchanges += 1;
            let mut p = self.feed.published;
            p.exchanges = exchanges;
            match &r {
                Ok(resp) => {
                    clock = Some((resp.extra.dc_system_time, monotonic_now()));
                    for i in 0..n {
                        let state = resp.subdevice_states.get(i).copied();
                        p.states[i] = match state {
                            Some(SubDeviceState::Op) => SubState::Op,
                            Some(SubDeviceState::None) | None => SubState::Lost,
                            Some(s) => SubState::NotOp(al_state(s)),
                        };
                    }
                    // The LRW's working counter: with every subdevice in Op, 3 from each (read
                    // and write); another count means the process image did not go through as
                    // set up, whatever the AL states say, and no input of this frame is
                    // trusted. (With one out of Op, what it adds depends on its state and the
                    // ESC; that one is faulted already.)
                    let all_op = p.states[..n].iter().all(|s| *s == SubState::Op);
                    if all_op && usize::from(resp.working_counter) != 3 * n {
                        p.states[..n].fill(SubState::Lost);
                    }
                    group.read(md, &mut p.inputs[..n]);
                }
                Err(_) => p.states[..n].fill(SubState::Lost),
            }
            self.feed.published = p;
            self.feed.input.publish(p);
            // EMCYs: every few cycles, each answering subdevice's input mailbox, after the
            // inputs are out (an emergency goes out with the next cycle's).
            if exchanges >= emcy_next && recovery.is_none() {
                emcy_next = exchanges + EMCY_POLL_CYCLES;
                for (i, s) in setups.iter().enumerate().take(n) {
                    if p.states[i] == SubState::Lost {
                        continue;
                    }
                    let facts = self.settings.devices[i];
                    let mut none = None;
                    if let Ok(Some(code)) =
                        self.pump
                            .run(read_emcy(md, s.address, facts), &mut none, &mut None)?
                    {
                        let e = &mut self.feed.published.emcy[i];
                        *e = (e.0.wrapping_add(1), code);
                        self.say(format!("subdevice {}: emergency {code:04X}h", i + 1));
                    }
                }
            }
            for (i, said) in said_lost.iter_mut().enumerate().take(n) {
                let bad = p.states[i] != SubState::Op;
                if bad && !*said {
                    let what = match p.states[i] {
                        SubState::NotOp(s) => format!("fell back to {s}"),
                        _ => "does not answer".into(),
                    };
                    self.say(format!("subdevice {} {what}", i + 1));
                }
                if !bad && *said {
                    self.say(format!("subdevice {} is back in Operational", i + 1));
                }
                *said = bad;
            }
            if let Some(done) = recovered.take() {
                // Said once per reason, not every attempt (every 200 ms while it is away).
                if let Err(e) = done.result
                    && last_failure.as_ref() != Some(&(done.index, e.clone()))
                {
                    self.say(format!(
                        "subdevice {} could not be brought back yet: {e}; trying again",
                        done.index + 1
                    ));
                    last_failure = Some((done.index, e));
                }
                next_try = monotonic_now() + Duration::from_millis(200);
            }
            if p.states[..n].iter().all(|s| *s == SubState::Op) {
                last_failure = None;
            }
            if recovery.is_none()
                && monotonic_now() >= next_try
                && let Some(i) = (0..n).find(|&i| p.states[i] != SubState::Op)
            {
                let facts = self.settings.devices[i];
                let setup = setups[i];
                let params = self.settings.parameters.get(i).cloned().unwrap_or_default();
                let dc = DcRestore {
                    // ethercrab takes the first subdevice with a clock as the reference; every
                    // subdevice here has one (the boot refuses others).
                    reference: setups[0].address,
                    period: self.settings.period,
                    clock,
                };
                let fut = recover(md, group, i, setup, facts, params, p.states[i], dc);
                recovery = Some(Box::pin(fut));
            }
        }
        Ok(())
    }
}

/// The AL state of one of ethercrab's subdevice states.
fn al_state(s: SubDeviceState) -> AlState {
    match s {
        SubDeviceState::Init => AlState::Init,
        SubDeviceState::PreOp => AlState::PreOp,
        SubDeviceState::Bootstrap => AlState::Boot,
        SubDeviceState::SafeOp => AlState::SafeOp,
        _ => AlState::Op,
    }
}

/// A group's process image, per subdevice.
trait GroupIo {
    fn write(&self, md: &MainDevice<'_>, images: &[[u8; 8]]);
    fn read(&self, md: &MainDevice<'_>, images: &mut [[u8; 8]]);
}

macro_rules! group_io {
    ($state:ty, $dc:ty) => {
        impl GroupIo for Group<$state, $dc> {
            fn write(&self, md: &MainDevice<'_>, images: &[[u8; 8]]) {
                for (sd, img) in self.iter(md).zip(images) {
                    let mut o = sd.outputs_raw_mut();
                    let k = o.len().min(8);
                    o[..k].copy_from_slice(&img[..k]);
                }
            }
            fn read(&self, md: &MainDevice<'_>, images: &mut [[u8; 8]]) {
                for (sd, img) in self.iter(md).zip(images.iter_mut()) {
                    let i = sd.inputs_raw();
                    let k = i.len().min(8);
                    img[..k].copy_from_slice(&i[..k]);
                }
            }
        }
    };
}
group_io!(subdevice_group::SafeOp, subdevice_group::HasDc);
group_io!(subdevice_group::Op, subdevice_group::HasDc);

/// The assignment, then the parameters.
async fn configure<S>(
    sd: &ethercrab::SubDeviceRef<'_, S>,
    facts: &EthercatFacts,
    parameters: &[(drivers::canopen::Address, u32, u8)],
) -> Result<(), String>
where
    S: core::ops::Deref<Target = ethercrab::SubDevice>,
{
    assign_pdos(sd, facts).await?;
    for &(a, value, size) in parameters {
        let r = match size {
            1 => sd.sdo_write(a.index, a.sub, value as u8).await,
            2 => sd.sdo_write(a.index, a.sub, value as u16).await,
            _ => sd.sdo_write(a.index, a.sub, value).await,
        };
        r.map_err(|e| format!("writing {:04X}h:{:02X}h = {value}: {e}", a.index, a.sub))?;
    }
    Ok(())
}

/// 1C12h and 1C13h: the catalog's cyclic PDOs, written (count 0, the entry, count 1) and read
/// back; and each PDO's mapping read and compared with the catalog's (the EMCA's mappings are
/// fixed: seed-002 §5.2 prints them, and a drive that maps otherwise would put other bytes
/// where the coordinator expects FHPP's).
async fn assign_pdos<S>(
    sd: &ethercrab::SubDeviceRef<'_, S>,
    facts: &EthercatFacts,
) -> Result<(), String>
where
    S: core::ops::Deref<Target = ethercrab::SubDevice>,
{
    let (rx, tx) = facts.cyclic_pdos();
    for p in [rx, tx] {
        let e = |x: Error| format!("reading the mapping {:04X}h: {x}", p.index);
        let count: u8 = sd.sdo_read(p.index, 0).await.map_err(e)?;
        let mut same = usize::from(count) == p.entries.len();
        for (k, &want) in p.entries.iter().enumerate().take(usize::from(count)) {
            let got: u32 = sd.sdo_read(p.index, k as u8 + 1).await.map_err(e)?;
            same &= got == want;
        }
        if !same {
            return Err(format!(
                "its PDO {:04X}h is not mapped as the catalog's ({} entries expected, {count} \
                 found, or other objects)",
                p.index,
                p.entries.len()
            ));
        }
    }
    for (index, pdo) in [(0x1C12u16, rx.index), (0x1C13, tx.index)] {
        let e = |what: &str, e: Error| format!("{index:04X}h {what}: {e}");
        sd.sdo_write(index, 0, 0u8)
            .await
            .map_err(|x| e("sub 0", x))?;
        sd.sdo_write(index, 1, pdo)
            .await
            .map_err(|x| e("sub 1", x))?;
        sd.sdo_write(index, 0, 1u8)
            .await
            .map_err(|x| e("sub 0", x))?;
        let count: u8 = sd.sdo_read(index, 0).await.map_err(|x| e("read back", x))?;
        let first: u16 = sd.sdo_read(index, 1).await.map_err(|x| e("read back", x))?;
        if (count, first) != (1, pdo) {
            return Err(format!(
                "the PDO assignment {index:04X}h did not take: it reads {count} PDO(s), the \
                 first {first:04X}h, after {pdo:04X}h was written"
            ));
        }
    }
    Ok(())
}

/// The sync managers and FMMUs ethercrab configured on the subdevice at `address`.
async fn read_setup(md: &MainDevice<'_>, address: u16) -> Result<EscSetup, String> {
    let mut s = EscSetup {
        address,
        ..EscSetup::EMPTY
    };
    let sm = Command::fprd(address, reg::SM0)
        .receive_slice(md, 32)
        .await
        .map_err(|e| format!("reading its sync managers: {e}"))?;
    s.sm.copy_from_slice(&sm[..32]);
    let fmmu = Command::fprd(address, reg::FMMU0)
        .receive_slice(md, 48)
        .await
        .map_err(|e| format!("reading its FMMUs: {e}"))?;
    s.fmmu.copy_from_slice(&fmmu[..48]);
    s.dc_delay = Command::fprd(address, reg::DC_SYSTEM_TIME_DELAY)
        .receive(md)
        .await
        .map_err(|e| format!("reading its DC delay: {e}"))?;
    Ok(s)
}

/// The emergency waiting in the subdevice's input mailbox, if one does: its error code. A
/// mailbox that holds something else is read (and so emptied) and ignored.
async fn read_emcy(
    md: &MainDevice<'_>,
    address: u16,
    facts: &EthercatFacts,
) -> Result<Option<u16>, Error> {
    // SM1's status register: bit 3, the mailbox is full.
    let status: u8 = Command::fprd(address, reg::SM0 + reg::SM_LEN + 5)
        .receive(md)
        .await?;
    if status & 0x08 == 0 {
        return Ok(None);
    }
    let (start, len) = facts.mailbox_in;
    let mbx = Command::fprd(address, start).receive_slice(md, len).await?;
    Ok(coe::parse_emergency(&mbx))
}

/// Asks for `state` and waits until the subdevice at `address` reports it.
async fn request_state(md: &MainDevice<'_>, address: u16, state: AlState) -> Result<(), String> {
    Command::fpwr(address, reg::AL_CONTROL)
        .send(md, state as u16)
        .await
        .map_err(|e| format!("asking for {state}: {e}"))?;
    let deadline = monotonic_now() + STATE_TIMEOUT;
    loop {
        let s: u16 = Command::fprd(address, reg::AL_STATUS)
            .receive(md)
            .await
            .map_err(|e| format!("waiting for {state}: {e}"))?;
        if s & 0x0F == state as u16 {
            if s & 0x10 != 0 {
                let code: u16 = Command::fprd(address, reg::AL_STATUS_CODE)
                    .receive(md)
                    .await
                    .unwrap_or(0);
                return Err(format!("{state} refused, AL status code {code:04X}h"));
            }
            return Ok(());
        }
        if s & 0x10 != 0 {
            let code: u16 = Command::fprd(address, reg::AL_STATUS_CODE)
                .receive(md)
                .await
                .unwrap_or(0);
            return Err(format!(
                "{state} refused, AL status code {code:04X}h (in {})",
                AlState::from_code((s & 0x0F) as u8)
                    .map_or("an unknown state".into(), |a| a.to_string())
            ));
        }
        if monotonic_now() > deadline {
            return Err(format!("{state} not reached within 2 s"));
        }
        yield_once().await;
    }
}

/// Lets the pump run once (the next poll comes after it sent and received).
async fn yield_once() {
    let mut yielded = false;
    std::future::poll_fn(|_| {
        if yielded {
            Poll::Ready(())
        } else {
            yielded = true;
            Poll::Pending
        }
    })
    .await
}

/// A power-cycled subdevice's clock and SYNC0: its offset so that its system time is the
/// segment's again (the reference's, or for the reference itself the time the last frame read,
/// carried forward), its delay as measured at the scan, and SYNC0 at the cycle's period,
/// starting [`SYNC0_START_DELAY`] from now on a multiple of the period.
async fn restore_clock(
    md: &MainDevice<'_>,
    address: u16,
    delay: u32,
    dc: DcRestore,
) -> Result<(), String> {
    fn e(what: &'static str) -> impl Fn(Error) -> String {
        move |x| format!("{what}: {x}")
    }
    let system: u64 = if address != dc.reference {
        Command::fprd(dc.reference, reg::DC_SYSTEM_TIME)
            .receive(md)
            .await
            .map_err(e("reading the reference clock"))?
    } else {
        let (t, at) = dc.clock.ok_or("no system time read yet")?;
        t.wrapping_add(monotonic_now().saturating_duration_since(at).as_nanos() as u64)
    };
    let local: u64 = Command::fprd(address, reg::DC_SYSTEM_TIME)
        .receive(md)
        .await
        .map_err(e("reading its clock"))?;
    Command::fpwr(address, reg::DC_SYSTEM_TIME_OFFSET)
        .send(md, system.wrapping_sub(local))
        .await
        .map_err(e("writing its clock offset"))?;
    Command::fpwr(address, reg::DC_SYSTEM_TIME_DELAY)
        .send(md, delay)
        .await
        .map_err(e("writing its clock delay"))?;
    let period = dc.period.as_nanos() as u64;
    let start = (system + SYNC0_START_DELAY.as_nanos() as u64) / period * period;
    Command::fpwr(address, reg::DC_ACTIVATION)
        .send(md, 0u8)
        .await
        .map_err(e("stopping SYNC0"))?;
    Command::fpwr(address, reg::DC_START_TIME)
        .send(md, start)
        .await
        .map_err(e("writing SYNC0's start"))?;
    Command::fpwr(address, reg::DC_SYNC0_CYCLE)
        .send(md, period as u32)
        .await
        .map_err(e("writing SYNC0's period"))?;
    Command::fpwr(address, reg::DC_ACTIVATION)
        .send(md, 0x03u8)
        .await
        .map_err(e("starting SYNC0"))?;
    Ok(())
}

/// Brings subdevice `index` back to Op beside the running cycle.
#[allow(clippy::too_many_arguments)]
async fn recover(
    md: &'static MainDevice<'static>,
    group: &OpGroup,
    index: usize,
    setup: EscSetup,
    facts: &'static EthercatFacts,
    parameters: Vec<(drivers::canopen::Address, u32, u8)>,
    seen: SubState,
    dc: DcRestore,
) -> Recovered {
    let result = async {
        let address = setup.address;
        // Its position on the line, 0 first (ethercrab turns it into the auto-increment
        // address, which counts down from 0).
        let position = index as u16;
        let station: u16 = Command::aprd(position, reg::STATION_ADDRESS)
            .receive(md)
            .await
            .map_err(|_| "it does not answer".to_owned())?;
        if station != address || matches!(seen, SubState::NotOp(AlState::Init)) {
            // Powered up again: a fresh ESC with no address and no configuration.
            Command::apwr(position, reg::STATION_ADDRESS)
                .send(md, address)
                .await
                .map_err(|e| format!("setting its station address: {e}"))?;
            Command::fpwr(address, reg::AL_CONTROL)
                .send(md, AlState::Init as u16 | 0x10)
                .await
                .map_err(|e| format!("resetting it: {e}"))?;
            Command::fpwr(address, reg::SM0)
                .send(md, &setup.sm[..16])
                .await
                .map_err(|e| format!("writing its mailbox sync managers: {e}"))?;
            request_state(md, address, AlState::PreOp).await?;
            // Whatever it queued in its input mailbox before (an emergency) must not be taken
            // for the answer to the assignment below.
            let _ = read_emcy(md, address, facts).await;
            let sd = group
                .subdevice(md, index)
                .map_err(|e| format!("its handle: {e}"))?;
            configure(&sd, facts, &parameters).await?;
            restore_clock(md, address, setup.dc_delay, dc).await?;
            Command::fpwr(address, reg::SM0 + 2 * reg::SM_LEN)
                .send(md, &setup.sm[16..])
                .await
                .map_err(|e| format!("writing its process-data sync managers: {e}"))?;
            Command::fpwr(address, reg::FMMU0)
                .send(md, &setup.fmmu[..])
                .await
                .map_err(|e| format!("writing its FMMUs: {e}"))?;
            request_state(md, address, AlState::SafeOp).await?;
        } else {
            // It kept its configuration and fell back (its watchdog, an error): acknowledge.
            let s: u16 = Command::fprd(address, reg::AL_STATUS)
                .receive(md)
                .await
                .map_err(|e| format!("reading its AL status: {e}"))?;
            let now = (s & 0x0F) as u8;
            if s & 0x10 != 0 {
                Command::fpwr(address, reg::AL_CONTROL)
                    .send(md, u16::from(now) | 0x10)
                    .await
                    .map_err(|e| format!("acknowledging its error: {e}"))?;
            }
            if now < AlState::SafeOp as u8 {
                request_state(md, address, AlState::SafeOp).await?;
            }
        }
        // The cycle's LRW gives it valid outputs in SafeOp; then Op.
        for _ in 0..3 {
            yield_once().await;
        }
        request_state(md, address, AlState::Op).await
    }
    .await;
    Recovered { index, result }
}

#[cfg(test)]
mod tests {
    use super::*;

    const OP: [SubState; 2] = [SubState::Op, SubState::Op];

    #[test]
    fn the_cycle_takes_each_exchange_once_with_its_state() {
        let (mut side, mut feed) = hand_over(2, Duration::from_millis(1));
        // Nothing exchanged yet: nothing fresh, nothing lost, no report.
        let i = side.take(0, 0);
        assert!(!i.fresh && !i.lost && i.not_op == 0, "{i:?}");
        assert_eq!(side.report(), None);
        feed.publish(&OP, &[[0x13, 0, 0, 0, 0, 0, 0, 0], [0x17; 8]], &[]);
        let (a, b) = (side.take(1, 0), side.take(1, 1));
        assert!(a.fresh && b.fresh);
        assert_eq!(a.image.bytes()[0], 0x13);
        assert_eq!(b.image.bytes()[7], 0x17);
        // Each subdevice reported once, when it first was in Op.
        assert_eq!(side.report(), Some((0, true)));
        assert_eq!(side.report(), Some((1, true)));
        assert_eq!(side.report(), None);
        // The same exchange is not fresh in the next cycle.
        assert!(!side.take(2, 0).fresh);
        // A subdevice out of Op: its state, no fresh inputs; one not answering: lost.
        feed.publish(
            &[SubState::NotOp(AlState::SafeOp), SubState::Lost],
            &[[0; 8]; 2],
            &[],
        );
        let (a, b) = (side.take(3, 0), side.take(3, 1));
        assert_eq!((a.fresh, a.not_op, a.lost), (false, 4, false));
        assert_eq!((b.fresh, b.lost), (false, true));
    }

    #[test]
    fn an_emergency_reaches_the_cycle_once() {
        let (mut side, mut feed) = hand_over(2, Duration::from_millis(1));
        feed.publish(&OP, &[[0; 8]; 2], &[(1, 0x3220)]);
        assert_eq!((side.take(1, 0).emcy, side.take(1, 1).emcy), (0, 0x3220));
        feed.publish(&OP, &[[0; 8]; 2], &[]);
        assert_eq!(side.take(2, 1).emcy, 0, "not again");
        feed.publish(&OP, &[[0; 8]; 2], &[(1, 0x3220)]);
        assert_eq!(
            side.take(3, 1).emcy,
            0x3220,
            "the same code again is a new one"
        );
    }

    #[test]
    fn a_bus_that_stops_exchanging_is_lost_after_its_limit() {
        // 10 ms: the limit is 3 cycles (30 ms); at 1 ms it would be 30.
        let (mut side, mut feed) = hand_over(1, Duration::from_millis(10));
        feed.publish(&OP[..1], &[[0; 8]], &[]);
        assert!(side.take(1, 0).fresh);
        assert!(!side.take(2, 0).lost);
        assert!(!side.take(3, 0).lost);
        assert!(side.take(4, 0).lost, "three cycles without an exchange");
        feed.publish(&OP[..1], &[[0; 8]], &[]);
        assert!(!side.take(5, 0).lost);
    }

    #[test]
    fn the_outputs_go_over_as_one_set_when_sent() {
        let (mut side, mut feed) = hand_over(2, Duration::from_millis(1));
        side.put(0, &[1; 8]);
        assert!(feed.outputs().is_none(), "not before send");
        side.put(1, &[2; 8]);
        side.send(7);
        let (cycle, images) = feed.outputs().expect("sent");
        assert_eq!((cycle, images[0], images[1]), (7, [1; 8], [2; 8]));
        assert!(feed.outputs().is_none(), "taken once");
    }
}
