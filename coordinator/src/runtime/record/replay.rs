//! `coordinator replay FILE`: the recorded machine's cycle built again from the configuration
//! the recording holds, run on the recorded inputs, and every frame it sends, every answer and
//! Modbus output it gives and every state it publishes compared with the recording; the first
//! difference is reported with its cycle, what differs, and the expected and found values.

use std::io::Read;
use std::path::Path;

use drivers::time::Instant;
use shm_api::contract::MachineState;

use super::format::{CycleRecord, ENDING_BEFORE, FormatError, Header, In, MAGIC, STOP_ASKED};
use super::format::{frame_text, read_cycle, reply_text};
use super::recorder::{boxed_state, recorded_state, state_bytes};
use crate::axis::Image;
use crate::command::{Answer, Request};
use crate::config::Config;
use crate::cycle::{BusFrame, ImageInput};
use crate::event::Event;
use crate::runtime::cycle_loop::{CycleIo, CycleLoop, NodeChange, Wake};
use crate::runtime::plan::plan;
use crate::runtime::run::Snapshot;
use crate::runtime::script::{Script, ScriptOptions};
use crate::runtime::shm::StaticInfo;
use crate::runtime::stepper::{RX_CAPACITY, Stepper, TX_CAPACITY};

/// A recording read into memory: its header and its records' bytes.
#[derive(Debug)]
pub struct Recording {
    /// The header.
    pub header: Header,
    data: Vec<u8>,
    start: usize,
    /// The file ends inside its compressed stream (a run that was killed): the records up to
    /// there replay.
    pub cut: bool,
}

impl Recording {
    /// Every whole cycle: its record and the state it published (a cut file's last, partial
    /// cycle left out).
    pub fn cycles(&self) -> Result<Vec<(CycleRecord, Vec<u8>)>, String> {
        let size = self.header.state_size as usize;
        let mut state = vec![0u8; size];
        let mut i = In::new(&self.data[self.start..]);
        let mut prev_now = Instant::from_nanos(self.header.start_ns);
        let mut out = Vec::new();
        while i.remaining() > 0 {
            let mut r = CycleRecord::with_capacity(0, 0, 0);
            match read_cycle(&mut i, prev_now, &mut r, &mut state) {
                Ok(()) => {}
                Err(FormatError::Truncated) if self.cut => break,
                Err(e) => return Err(format!("cycle {}: {e}", out.len())),
            }
            prev_now = r.wake.now;
            out.push((r, state.clone()));
        }
        Ok(out)
    }

    /// Reads and decompresses `path`.
    pub fn open(path: &Path) -> Result<Recording, String> {
        let bytes =
            std::fs::read(path).map_err(|e| format!("cannot read {}: {e}", path.display()))?;
        let Some(body) = bytes.strip_prefix(MAGIC.as_slice()) else {
            return Err(format!(
                "{} is not a recording of `coordinator run --record` (it does not start with its mark)",
                path.display()
            ));
        };
        let mut data = Vec::new();
        let mut z = flate2::read::ZlibDecoder::new(body);
        // A killed run leaves a stream without its end: keep what decompressed.
        let cut = z.read_to_end(&mut data).is_err();
        let mut i = In::new(&data);
        let bad = |e: FormatError| format!("{}: the header: {e}", path.display());
        let n: usize = i.uv_as("header length").map_err(bad)?;
        let mut h = In::new(i.bytes(n).map_err(bad)?);
        let header = Header::decode(&mut h).map_err(bad)?;
        let start = data.len() - i.remaining();
        Ok(Recording {
            header,
            data,
            start,
            cut,
        })
    }
}

/// How a replay ended.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum Outcome {
    /// Every cycle matched.
    Identical,
    /// The first difference.
    Diverged {
        /// The cycle (0 is the first).
        cycle: u64,
        /// What differs, expected and found, in words.
        what: String,
    },
}

/// What a replay did.
#[derive(Debug, Clone)]
pub struct ReplaySummary {
    /// Cycles replayed (up to and including a divergent one).
    pub cycles: u64,
    /// Machine time of the last cycle replayed, from the first.
    pub machine_time: std::time::Duration,
    /// Frames sent and compared.
    pub frames: u64,
    /// States compared.
    pub states: u64,
    /// Client commands fed to the cycle.
    pub commands: u64,
    /// The recording ended inside its stream (a killed run).
    pub cut: bool,
    /// The result.
    pub outcome: Outcome,
}

impl std::fmt::Display for ReplaySummary {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        let t = self.machine_time.as_secs_f64();
        match &self.outcome {
            Outcome::Identical => {
                let commands = match self.commands {
                    0 => "no client commands".to_string(),
                    1 => "1 client command".to_string(),
                    n => format!("{n} client commands"),
                };
                write!(
                    f,
                    "replay: {} cycles ({t:.3} s of machine time, {commands}): every frame sent ({}) and every state published ({}) identical to the recording",
                    self.cycles, self.frames, self.states
                )?;
                if self.cut {
                    write!(
                        f,
                        "\nnote: the recording ends early (its run was killed): replayed up to its last whole cycle"
                    )?;
                }
                Ok(())
            }
            Outcome::Diverged { cycle, what } => write!(
                f,
                "replay: DIVERGED at cycle {cycle} ({t:.3} s of machine time): {what}"
            ),
        }
    }
}

/// The recorded inputs of one cycle handed out in the order the loop asks for them, and its
/// outputs compared as they come.
struct ReplayIo<'r> {
    rec: &'r CycleRecord,
    reports: usize,
    modbus_in: usize,
    requests: usize,
    service: usize,
    sent: usize,
    answers: usize,
    modbus_out: usize,
    /// The first difference in this cycle.
    diverged: Option<String>,
}

impl ReplayIo<'_> {
    fn diverge(&mut self, what: String) {
        if self.diverged.is_none() {
            self.diverged = Some(what);
        }
    }

    /// What the loop did not take or send that the recording has.
    fn leftovers(&mut self) {
        let r = self.rec;
        if let Some((f, _)) = r.sent.get(self.sent) {
            self.diverge(format!(
                "frame {} not sent: expected {}, the cycle sent {} frames",
                self.sent + 1,
                frame_text(f),
                self.sent
            ));
        }
        if let Some((tag, text)) = r.answers.get(self.answers) {
            self.diverge(format!("no answer to request {tag}: expected \"{text}\""));
        }
        if self.requests < r.requests.len() {
            self.diverge(format!(
                "{} recorded client requests were not taken",
                r.requests.len() - self.requests
            ));
        }
        if self.service < r.service.len() {
            self.diverge(format!(
                "{} recorded boot frames were not taken",
                r.service.len() - self.service
            ));
        }
        if self.reports < r.reports.len() {
            self.diverge(format!(
                "{} recorded drive reports were not taken",
                r.reports.len() - self.reports
            ));
        }
        if self.modbus_out < r.modbus_out.len() {
            self.diverge(format!(
                "{} Modbus outputs missing",
                r.modbus_out.len() - self.modbus_out
            ));
        }
    }
}

fn image_text(m: &Image) -> String {
    let b: Vec<String> = m.bytes().iter().map(|b| format!("{b:02X}")).collect();
    if b.is_empty() {
        "(no bytes)".into()
    } else {
        b.join(" ")
    }
}

impl CycleIo for ReplayIo<'_> {
    fn wait(&mut self, rx: &mut dyn FnMut(BusFrame)) -> Wake {
        for f in &self.rec.rx {
            rx(*f);
        }
        self.rec.wake
    }

    fn node_report(&mut self) -> Option<NodeChange> {
        let &(axis, status) = self.rec.reports.get(self.reports)?;
        self.reports += 1;
        Some(NodeChange { axis, status })
    }

    fn image_input(&mut self, _k: u64, slot: usize, _last: &Image, _now: Instant) -> ImageInput {
        match self.rec.modbus_in.get(self.modbus_in) {
            Some(m) => {
                self.modbus_in += 1;
                *m
            }
            None => {
                self.diverge(format!(
                    "the cycle asked for Modbus slot {slot}'s input, which the recording does not have"
                ));
                ImageInput::default()
            }
        }
    }

    fn image_output(&mut self, _k: u64, slot: usize, output: &Image) {
        let n = self.modbus_out;
        self.modbus_out += 1;
        match self.rec.modbus_out.get(n) {
            Some(m) if m == output => {}
            Some(m) => self.diverge(format!(
                "Modbus slot {slot}'s output: expected {}, found {}",
                image_text(m),
                image_text(output)
            )),
            None => self.diverge(format!(
                "Modbus slot {slot}'s output {} is not in the recording",
                image_text(output)
            )),
        }
    }

    fn request(&mut self) -> Option<Request> {
        let r = *self.rec.requests.get(self.requests)?;
        self.requests += 1;
        Some(r)
    }

    fn answer(&mut self, answer: Answer) {
        let n = self.answers;
        self.answers += 1;
        let found = reply_text(&answer.reply);
        match self.rec.answers.get(n) {
            Some((tag, text)) if *tag == answer.tag && *text == found => {}
            Some((tag, text)) => self.diverge(format!(
                "answer to request {tag}: expected \"{text}\", found \"{found}\" (request {})",
                answer.tag
            )),
            None => self.diverge(format!(
                "an answer the recording does not have: request {}, \"{found}\"",
                answer.tag
            )),
        }
    }

    fn send(&mut self, frame: &BusFrame) -> bool {
        let n = self.sent;
        self.sent += 1;
        match self.rec.sent.get(n) {
            Some((f, ok)) if f.bus == frame.bus && f.frame == frame.frame => *ok,
            Some((f, ok)) => {
                self.diverge(format!(
                    "frame {} sent: expected {}, found {}",
                    n + 1,
                    frame_text(f),
                    frame_text(frame)
                ));
                *ok
            }
            None => {
                self.diverge(format!(
                    "frame {} sent, {}, is not in the recording (it has {} frames in this cycle)",
                    n + 1,
                    frame_text(frame),
                    self.rec.sent.len()
                ));
                true
            }
        }
    }

    fn service_frame(&mut self, _now: Instant) -> Option<BusFrame> {
        let f = *self.rec.service.get(self.service)?;
        self.service += 1;
        Some(f)
    }

    fn stop_asked(&mut self, _flag: &std::sync::atomic::AtomicBool) -> bool {
        self.rec.flags & STOP_ASKED != 0
    }

    fn event(&mut self, _e: Event) {}

    fn status(&mut self, _snapshot: Snapshot) {}
}

/// The name of the state's field at byte `at`, its first byte and its size (`axes[1].position`).
pub fn state_field(at: usize) -> (String, usize, usize) {
    let layouts = shm_api::layout_dump::layouts();
    let find = |name: &str| layouts.iter().find(|t| t.name == name);
    let mut path = String::new();
    let mut base = 0usize;
    let mut ty = "MachineState";
    loop {
        let Some(t) = find(ty) else {
            return (path, base, 1);
        };
        let Some(f) = t
            .fields
            .iter()
            .find(|f| (base + f.offset..base + f.offset + f.size).contains(&at))
        else {
            return (path, base, t.size);
        };
        if !path.is_empty() {
            path.push('.');
        }
        path.push_str(f.name);
        let start = base + f.offset;
        // The contract's nested structs: a field of one, or an array of them.
        let inner = match (ty, f.name) {
            ("MachineState", "bus") => Some("BusStats"),
            ("MachineState", "axes") => Some("AxisState"),
            ("MachineState", "groups") => Some("GroupState"),
            _ => None,
        };
        match inner.and_then(|n| find(n).map(|t| (n, t.size))) {
            Some((n, size)) if size > 0 => {
                if f.size > size {
                    let k = (at - start) / size;
                    path.push_str(&format!("[{k}]"));
                    base = start + k * size;
                } else {
                    base = start;
                }
                ty = n;
            }
            _ => return (path, start, f.size),
        }
    }
}

/// A state field's value in words: a little-endian integer where it is one.
fn field_value(b: &[u8]) -> String {
    match b.len() {
        1 => b[0].to_string(),
        2 => i16::from_le_bytes([b[0], b[1]]).to_string(),
        4 => i32::from_le_bytes([b[0], b[1], b[2], b[3]]).to_string(),
        8 => i64::from_le_bytes([b[0], b[1], b[2], b[3], b[4], b[5], b[6], b[7]]).to_string(),
        _ => {
            // Text fields (names) read as text; other arrays as bytes.
            let t = b.split(|&c| c == 0).next().unwrap_or(&[]);
            let padded = b[t.len()..].iter().all(|&c| c == 0);
            match std::str::from_utf8(t) {
                Ok(s) if !s.is_empty() && padded && !s.contains(char::is_control) => {
                    format!("\"{s}\"")
                }
                _ => b
                    .iter()
                    .map(|c| format!("{c:02X}"))
                    .collect::<Vec<_>>()
                    .join(" "),
            }
        }
    }
}

/// Replays `path`, printing a line when it starts; returns what it found.
pub fn replay(path: &Path, out: &mut dyn std::io::Write) -> Result<ReplaySummary, String> {
    let rec = Recording::open(path)?;
    let h = &rec.header;
    let size = std::mem::size_of::<MachineState>();
    if h.layout_hash != shm_api::contract::LAYOUT_HASH || h.state_size as usize != size {
        return Err(format!(
            "{}: recorded with the state layout {:08x} ({} bytes); this coordinator publishes {:08x} ({size} bytes): replay it with the coordinator that recorded it ({})",
            path.display(),
            h.layout_hash,
            h.state_size,
            shm_api::contract::LAYOUT_HASH,
            h.recorder
        ));
    }
    let cfg = Config::parse(&h.config)
        .map_err(|e| format!("{}: the recorded configuration: {e}", path.display()))?;
    let plan = plan(&cfg).map_err(|e| format!("{}: the recorded machine: {e}", path.display()))?;
    let _ = writeln!(
        out,
        "replaying {}: {} axes, cycle {} µs, {}, recorded by {}",
        path.display(),
        plan.axes.len(),
        plan.period.as_micros(),
        if h.virtual_time {
            "virtual time"
        } else {
            "real time"
        },
        h.recorder
    );
    let start = Instant::from_nanos(h.start_ns);
    let script = ScriptOptions {
        demo: h.script[0],
        chains: h.script[1],
        home: h.script[2],
    };
    let mut stepper = Stepper::new(&plan).map_err(|e| e.to_string())?;
    let mut lp = CycleLoop::new(
        &plan,
        Script::new(script, start),
        None,
        start,
        h.duration_ns.map(std::time::Duration::from_nanos),
        None,
    )
    .map_err(|e| e.to_string())?;
    let info = StaticInfo::new(&plan, h.virtual_time);
    let modbus = plan.image_slots();
    let mut record = CycleRecord::with_capacity(RX_CAPACITY + 64, TX_CAPACITY, modbus);
    let mut expected = vec![0u8; size];
    let mut found = boxed_state();
    let mut i = In::new(&rec.data[rec.start..]);
    let mut prev_now = start;
    let mut summary = ReplaySummary {
        cycles: 0,
        machine_time: std::time::Duration::ZERO,
        frames: 0,
        states: 0,
        commands: 0,
        cut: rec.cut,
        outcome: Outcome::Identical,
    };
    let mut running = true;
    while i.remaining() > 0 {
        let k = summary.cycles;
        // One whole record (the inputs and outputs, then the state), or the end of a cut file.
        match read_cycle(&mut i, prev_now, &mut record, &mut expected) {
            Ok(()) => {}
            Err(FormatError::Truncated) if rec.cut => break,
            Err(e) => return Err(format!("{}: cycle {k}: {e}", path.display())),
        }
        prev_now = record.wake.now;
        if !running {
            summary.outcome = Outcome::Diverged {
                cycle: k,
                what: "the run ended in the cycle before; the recording goes on".into(),
            };
            break;
        }
        if record.flags & ENDING_BEFORE != 0 {
            lp.shut_down();
        }
        let mut io = ReplayIo {
            rec: &record,
            reports: 0,
            modbus_in: 0,
            requests: 0,
            service: 0,
            sent: 0,
            answers: 0,
            modbus_out: 0,
            diverged: None,
        };
        running = lp.iterate(&mut stepper, &mut io).is_some();
        io.leftovers();
        summary.cycles += 1;
        summary.machine_time = record.wake.now.saturating_duration_since(start);
        summary.frames += io.sent as u64;
        summary.commands += io.requests as u64;
        if let Some(what) = io.diverged {
            summary.outcome = Outcome::Diverged { cycle: k, what };
            break;
        }
        let late_us = record.wake.late_us();
        recorded_state(
            &mut found,
            &info,
            &stepper.cycle,
            record.wake.now,
            stepper.counters(lp.skipped, late_us),
        );
        let got = state_bytes(&found);
        summary.states += 1;
        if let Some(at) = expected.iter().zip(got).position(|(a, b)| a != b) {
            let (name, from, n) = state_field(at);
            summary.outcome = Outcome::Diverged {
                cycle: k,
                what: format!(
                    "state field {name}: expected {}, found {}",
                    field_value(&expected[from..from + n]),
                    field_value(&got[from..from + n])
                ),
            };
            break;
        }
    }
    Ok(summary)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_state_byte_is_named_by_its_field() {
        let axes = std::mem::offset_of!(MachineState, axes);
        let axis = std::mem::size_of::<shm_api::contract::AxisState>();
        let (name, from, n) = state_field(axes + axis + 2);
        assert!(name.starts_with("axes[1]."), "{name}");
        assert!(from >= axes + axis && from + n <= axes + 2 * axis);
        let (name, from, n) = state_field(std::mem::offset_of!(MachineState, cycle));
        assert_eq!((name.as_str(), n), ("cycle", 8));
        assert_eq!(from, std::mem::offset_of!(MachineState, cycle));
        let (name, _, _) = state_field(std::mem::offset_of!(MachineState, bus) + 1);
        assert!(name.starts_with("bus."), "{name}");
    }

    #[test]
    fn values_read_as_integers_or_text() {
        assert_eq!(field_value(&(-5i64).to_le_bytes()), "-5");
        assert_eq!(field_value(&7u32.to_le_bytes()), "7");
        assert_eq!(field_value(b"x\0\0\0\0\0\0\0\0\0\0\0\0\0\0\0"), "\"x\"");
    }
}
