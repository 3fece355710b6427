//! `coordinator run --record FILE`: the cycle thread's side ([`Recorder`], [`Tap`]) and the
//! writer thread that compresses the records into the file.
//!
//! The cycle thread fills one preallocated [`CycleRecord`] through [`Tap`], a [`CycleIo`] that
//! passes every call through and keeps what crossed it; at the end of the cycle it encodes the
//! record and the state it published into a preallocated buffer and hands the bytes to the
//! writer through a wait-free single-producer ring (`rtrb`): no allocation, no lock, no system
//! call. The writer turns each state into its difference from the previous one and deflates the
//! stream into the file. In real time a ring that is full (the disk cannot keep up) ends the
//! recording there, counted and reported, rather than delaying a cycle; in virtual time the
//! cycle waits for the writer.

use std::io::Write;
use std::path::{Path, PathBuf};
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};
use std::thread::JoinHandle;
use std::time::Duration;

use drivers::time::Instant;
use shm_api::contract::MachineState;

use super::format::{
    CycleRecord, Header, MAGIC, Out, STOP_ASKED, append_cycle, put_uv, reply_text,
};
use crate::axis::Image;
use crate::command::{Answer, Request};
use crate::cycle::{BusFrame, ImageInput};
use crate::event::Event;
use crate::runtime::cycle_loop::{CycleIo, NodeChange, Wake};
use crate::runtime::plan::MachinePlan;
use crate::runtime::run::Snapshot;
use crate::runtime::shm::{Counters, StaticInfo, fill_state};
use crate::runtime::stepper::{RX_CAPACITY, Stepper, TX_CAPACITY};

/// The ring between the cycle thread and the writer: about 480 cycles of the largest state and
/// a busy cycle's frames, a second at 2 ms.
const RING_BYTES: usize = 8 << 20;
/// The largest encoded record (every frame a cycle may receive and send, with room).
const RECORD_BYTES: usize = 32 * (RX_CAPACITY + TX_CAPACITY) + 64 * 1024;

/// The published state's bytes.
pub fn state_bytes(s: &MachineState) -> &[u8] {
    // SAFETY: `MachineState` is `#[repr(C)]` of integers and arrays of `#[repr(C)]` structs of
    // integers with every gap an explicit `reserved` field (the contract's layout; the test
    // `the_state_has_no_hidden_padding` holds it), so all its bytes are initialised.
    unsafe {
        std::slice::from_raw_parts(
            (s as *const MachineState).cast::<u8>(),
            std::mem::size_of::<MachineState>(),
        )
    }
}

/// The state as a recording holds it: as published, with the two figures that measure the
/// machine that ran it rather than the cycle (the step's compute time and the publication's
/// time stamp) zeroed.
pub fn recorded_state<const A: usize, const G: usize>(
    out: &mut MachineState,
    info: &StaticInfo,
    c: &crate::cycle::Cycle<'_, A, G>,
    now: Instant,
    counters: Counters,
) {
    let counters = Counters {
        step_ns: 0,
        ..counters
    };
    fill_state(out, info, c, now.as_nanos(), 0, &counters);
}

/// A new zeroed state on the heap (17 KB: not on the stack).
pub fn boxed_state() -> Box<MachineState> {
    // SAFETY: every field of the contract's state is an integer (or an array of them): all
    // zero bytes is a valid value.
    unsafe { Box::<MachineState>::new_zeroed().assume_init() }
}

/// What a recording wrote.
#[derive(Debug, Clone, Default)]
pub struct RecordStats {
    /// The file.
    pub path: PathBuf,
    /// Cycles recorded.
    pub cycles: u64,
    /// Bytes in the file.
    pub file_bytes: u64,
    /// The cycle at which the recording stopped early, and why, if it did.
    pub stopped_at: Option<(u64, &'static str)>,
    /// Why the writer failed, if it did.
    pub error: Option<String>,
}

impl RecordStats {
    /// The summary's line.
    pub fn line(&self) -> String {
        let mb = self.file_bytes as f64 / 1e6;
        let mut s = format!(
            "recording: {} cycles in {} ({mb:.2} MB); replay it with `coordinator replay {}`",
            self.cycles,
            self.path.display(),
            self.path.display()
        );
        if let Some((k, why)) = self.stopped_at {
            s.push_str(&format!(
                "; STOPPED EARLY at cycle {k}: {why} (the recording replays up to there)"
            ));
        }
        if let Some(e) = &self.error {
            s.push_str(&format!("; FAILED: {e}"));
        }
        s
    }
}

/// The cycle thread's side of a recording.
pub struct Recorder {
    record: CycleRecord,
    scratch: Box<[u8]>,
    state: Box<MachineState>,
    info: StaticInfo,
    ring: rtrb::Producer<u8>,
    prev_now: Instant,
    /// Virtual time: wait for room in the ring instead of ending the recording.
    wait_for_room: bool,
    cycles: u64,
    stopped_at: Option<(u64, &'static str)>,
    done: Arc<AtomicBool>,
    writer: Option<JoinHandle<Result<u64, String>>>,
    path: PathBuf,
}

impl std::fmt::Debug for Recorder {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Recorder")
            .field("cycles", &self.cycles)
            .finish_non_exhaustive()
    }
}

impl Recorder {
    /// Creates `path`, writes the header and starts the writer thread. Everything the cycle
    /// thread will need is allocated here.
    pub fn create(
        path: &Path,
        plan: &MachinePlan,
        config_text: &str,
        header: Header,
    ) -> Result<Recorder, String> {
        let header = Header {
            config: config_text.to_string(),
            ..header
        };
        let z =
            create_file(path, &header).map_err(|e| format!("--record {}: {e}", path.display()))?;
        let (ring, consumer) = rtrb::RingBuffer::new(RING_BYTES);
        let done = Arc::new(AtomicBool::new(false));
        let d = done.clone();
        let writer = std::thread::Builder::new()
            .name("record-writer".into())
            .spawn(move || write_records(consumer, z, &d))
            .map_err(|e| format!("--record: cannot start the writer thread: {e}"))?;
        let modbus = plan.image_slots();
        Ok(Recorder {
            record: CycleRecord::with_capacity(RX_CAPACITY + 64, TX_CAPACITY, modbus),
            scratch: vec![0u8; RECORD_BYTES].into_boxed_slice(),
            state: boxed_state(),
            info: StaticInfo::new(plan, header.virtual_time),
            ring,
            prev_now: Instant::from_nanos(header.start_ns),
            wait_for_room: header.virtual_time,
            cycles: 0,
            stopped_at: None,
            done,
            writer: Some(writer),
            path: path.to_path_buf(),
        })
    }

    /// Starts a cycle's record; `ending_before`: the orderly end was asked for from outside the
    /// loop since the last cycle.
    pub fn begin(&mut self, ending_before: bool) {
        self.record.clear();
        if ending_before {
            self.record.flags |= super::format::ENDING_BEFORE;
        }
    }

    /// The record being filled (for [`Tap`]).
    pub fn record(&mut self) -> &mut CycleRecord {
        &mut self.record
    }

    /// Ends the cycle `k`: encodes its record and the state it produced and hands both to the
    /// writer. Allocation-free.
    pub fn end(&mut self, k: u64, stepper: &Stepper<'_>, counters: Counters) {
        if self.stopped_at.is_some() {
            return;
        }
        let now = self.record.wake.now;
        recorded_state(&mut self.state, &self.info, &stepper.cycle, now, counters);
        let (len, ok) = {
            let (head, body) = self.scratch.split_at_mut(4);
            let mut o = Out::new(body);
            let ok = !self.record.overflow && self.record.encode(self.prev_now, &mut o).is_ok();
            let len = o.len();
            head.copy_from_slice(&(len as u32).to_le_bytes());
            (len, ok)
        };
        let state = state_bytes(&self.state);
        let need = 4 + len + state.len();
        if !ok {
            self.stopped_at = Some((
                k,
                "more frames or commands arrived in one cycle than a record holds",
            ));
            return;
        }
        while self.ring.slots() < need {
            if !self.wait_for_room || self.ring.is_abandoned() {
                self.stopped_at = Some((k, "the writer could not keep up with the cycle"));
                return;
            }
            std::thread::sleep(Duration::from_micros(200));
        }
        // Room was checked: each write takes all its bytes.
        let _ = self.ring.write_all(&self.scratch[..4 + len]);
        let _ = self.ring.write_all(state);
        self.prev_now = now;
        self.cycles += 1;
    }

    /// Ends the recording: the writer drains the ring and closes the file.
    pub fn finish(mut self) -> RecordStats {
        // (`Drop` does the same for a recording never finished.)
        self.done.store(true, Ordering::Release);
        let result = self.writer.take().map(|w| {
            w.join()
                .unwrap_or_else(|_| Err("the writer thread panicked".into()))
        });
        let mut stats = RecordStats {
            path: self.path.clone(),
            cycles: self.cycles,
            file_bytes: 0,
            stopped_at: self.stopped_at,
            error: None,
        };
        match result {
            Some(Ok(bytes)) => stats.file_bytes = bytes,
            Some(Err(e)) => stats.error = Some(e),
            None => {}
        }
        stats
    }
}

type Stream = flate2::write::ZlibEncoder<std::io::BufWriter<std::fs::File>>;

/// Creates a recording file: its mark, then the compressed stream with the header.
fn create_file(path: &Path, header: &Header) -> std::io::Result<Stream> {
    let mut file = std::io::BufWriter::new(std::fs::File::create(path)?);
    file.write_all(MAGIC)?;
    let mut z = flate2::write::ZlibEncoder::new(file, flate2::Compression::fast());
    let mut hb = Vec::new();
    header.encode(&mut hb);
    let mut o = Vec::new();
    put_uv(hb.len() as u64, &mut o);
    o.extend_from_slice(&hb);
    z.write_all(&o)?;
    Ok(z)
}

/// Closes a recording's stream and file; returns its size.
fn close_file(z: Stream) -> std::io::Result<u64> {
    let mut file = z.finish()?;
    file.flush()?;
    let file = file.into_inner().map_err(|e| e.into_error())?;
    file.sync_all()?;
    Ok(file.metadata().map(|m| m.len()).unwrap_or(0))
}

/// Writes a whole recording from records already in memory (tools and tests: a recording cut,
/// or changed on purpose to check that the replay finds the change). Each state is
/// `size_of::<MachineState>()` bytes.
pub fn write_recording(
    path: &Path,
    header: &Header,
    cycles: &[(CycleRecord, Vec<u8>)],
) -> Result<u64, String> {
    let err = |e: &dyn std::fmt::Display| format!("{}: {e}", path.display());
    let mut z = create_file(path, header).map_err(|e| err(&e))?;
    let size = std::mem::size_of::<MachineState>();
    let mut prev = vec![0u8; size];
    let (mut d, mut out) = (Vec::new(), Vec::new());
    let mut buf = vec![0u8; RECORD_BYTES];
    let mut prev_now = Instant::from_nanos(header.start_ns);
    for (r, state) in cycles {
        let mut o = Out::new(&mut buf);
        r.encode(prev_now, &mut o).map_err(|e| err(&e))?;
        if state.len() != size {
            return Err(err(&"a state of the wrong size"));
        }
        out.clear();
        append_cycle(&mut out, o.written(), &mut prev, state, &mut d);
        z.write_all(&out).map_err(|e| err(&e))?;
        prev_now = r.wake.now;
    }
    close_file(z).map_err(|e| err(&e))
}

/// The writer thread: records out of the ring, each state as its difference from the last,
/// into the deflate stream; returns the file's size.
fn write_records(
    mut ring: rtrb::Consumer<u8>,
    mut z: Stream,
    done: &AtomicBool,
) -> Result<u64, String> {
    let size = std::mem::size_of::<MachineState>();
    let mut buf: Vec<u8> = Vec::with_capacity(RING_BYTES);
    let mut prev = vec![0u8; size];
    let mut d = Vec::with_capacity(size);
    let mut out = Vec::with_capacity(size * 2);
    let err = |e: std::io::Error| format!("writing the recording: {e}");
    loop {
        // Read `done` before draining: whatever the cycle wrote before setting it is in the
        // ring by then.
        let finished = done.load(Ordering::Acquire);
        let n = ring.slots();
        if n > 0
            && let Ok(chunk) = ring.read_chunk(n)
        {
            let (a, b) = chunk.as_slices();
            buf.extend_from_slice(a);
            buf.extend_from_slice(b);
            chunk.commit_all();
        }
        let mut at = 0;
        while buf.len() - at >= 4 {
            let len = u32::from_le_bytes([buf[at], buf[at + 1], buf[at + 2], buf[at + 3]]) as usize;
            if buf.len() - at < 4 + len + size {
                break;
            }
            let payload = &buf[at + 4..at + 4 + len];
            let state = &buf[at + 4 + len..at + 4 + len + size];
            out.clear();
            append_cycle(&mut out, payload, &mut prev, state, &mut d);
            z.write_all(&out).map_err(err)?;
            at += 4 + len + size;
        }
        buf.drain(..at);
        if finished && ring.is_empty() {
            break;
        }
        if ring.is_empty() {
            std::thread::sleep(Duration::from_millis(1));
        }
    }
    close_file(z).map_err(err)
}

/// A [`CycleIo`] that passes every call to `io` and keeps in `rec` what entered the cycle and
/// what it put out.
pub struct Tap<'a, I> {
    /// The real I/O.
    pub io: &'a mut I,
    /// The cycle's record.
    pub rec: &'a mut CycleRecord,
}

impl Drop for Recorder {
    fn drop(&mut self) {
        // A run that ends without `finish` (an error, a test) still closes its file.
        self.done.store(true, Ordering::Release);
        if let Some(w) = self.writer.take() {
            let _ = w.join();
        }
    }
}

fn keep<T>(v: &mut Vec<T>, x: T, overflow: &mut bool) {
    // Within capacity: a push never allocates; beyond it the record is marked instead.
    if v.len() < v.capacity() {
        v.push(x);
    } else {
        *overflow = true;
    }
}

impl<I: CycleIo> CycleIo for Tap<'_, I> {
    fn wait(&mut self, rx: &mut dyn FnMut(BusFrame)) -> Wake {
        let rec = &mut *self.rec;
        let w = self.io.wait(&mut |f| {
            keep(&mut rec.rx, f, &mut rec.overflow);
            rx(f);
        });
        rec.wake = w;
        w
    }

    fn node_report(&mut self) -> Option<NodeChange> {
        let r = self.io.node_report()?;
        keep(
            &mut self.rec.reports,
            (r.axis, r.status),
            &mut self.rec.overflow,
        );
        Some(r)
    }

    fn image_input(&mut self, k: u64, slot: usize, last: &Image, now: Instant) -> ImageInput {
        let m = self.io.image_input(k, slot, last, now);
        keep(&mut self.rec.modbus_in, m, &mut self.rec.overflow);
        m
    }

    fn image_output(&mut self, k: u64, slot: usize, output: &Image) {
        keep(&mut self.rec.modbus_out, *output, &mut self.rec.overflow);
        self.io.image_output(k, slot, output);
    }

    fn images_sent(&mut self, k: u64) {
        self.io.images_sent(k);
    }

    fn request(&mut self) -> Option<Request> {
        let r = self.io.request()?;
        keep(&mut self.rec.requests, r, &mut self.rec.overflow);
        Some(r)
    }

    fn answer(&mut self, answer: Answer) {
        keep(
            &mut self.rec.answers,
            (answer.tag, reply_text(&answer.reply)),
            &mut self.rec.overflow,
        );
        self.io.answer(answer);
    }

    fn send(&mut self, frame: &BusFrame) -> bool {
        let ok = self.io.send(frame);
        keep(&mut self.rec.sent, (*frame, ok), &mut self.rec.overflow);
        ok
    }

    fn service_frame(&mut self, now: Instant) -> Option<BusFrame> {
        let f = self.io.service_frame(now)?;
        keep(&mut self.rec.service, f, &mut self.rec.overflow);
        Some(f)
    }

    fn stop_asked(&mut self, flag: &AtomicBool) -> bool {
        let s = self.io.stop_asked(flag);
        if s {
            self.rec.flags |= STOP_ASKED;
        }
        s
    }

    fn event(&mut self, e: Event) {
        self.io.event(e);
    }

    fn status(&mut self, snapshot: Snapshot) {
        self.io.status(snapshot);
    }
}

#[cfg(test)]
mod tests {

    #[test]
    fn the_state_has_no_hidden_padding() {
        // `state_bytes` reads every byte of the state: each type's fields must cover it.
        for t in shm_api::layout_dump::layouts() {
            if !matches!(
                t.name,
                "MachineState" | "AxisState" | "GroupState" | "BusStats"
            ) {
                continue;
            }
            let mut fields = t.fields.clone();
            fields.sort_by_key(|f| f.offset);
            let mut at = 0;
            for f in &fields {
                assert_eq!(f.offset, at, "{}: a gap before {}", t.name, f.name);
                at += f.size;
            }
            assert_eq!(at, t.size, "{}: a gap at the end", t.name);
        }
    }
}
