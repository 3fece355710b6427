//! The recording's bytes: one header, then one record per cycle, each the inputs that entered
//! the cycle and the outputs it produced, sans I/O (encoded into and decoded from byte slices).
//!
//! Integers are LEB128 varints (signed ones zigzagged), times are nanoseconds relative to the
//! cycle's SYNC time, and every multi-byte fixed field is little-endian: a recording made on one
//! machine replays on any other. The published state travels beside a record as its raw bytes;
//! the writer stores it as the difference from the previous cycle's ([`delta`]).

use drivers::can::Frame;
use drivers::time::Instant;
use embedded_can::{ExtendedId, Id, StandardId};

use crate::axis::{IMAGE_BYTES, Image};
use crate::command::{BufferMode, Command, Rejected, Reply, Request, Target};
use crate::cycle::{BusFrame, ImageInput};
use crate::ids::MAX_GROUP_AXES;
use crate::runtime::cycle_loop::Wake;
use crate::runtime::nodes::NodeStatus;

/// The first bytes of a recording file (before the compressed stream).
pub const MAGIC: &[u8; 8] = b"MOTNREC\0";
/// The format's version: a reader refuses any other.
pub const VERSION: u16 = 1;

/// [`CycleRecord::flags`]: the orderly end was asked for from outside the loop before this
/// cycle (`VirtualRun::shut_down`, a test).
pub const ENDING_BEFORE: u8 = 1;
/// [`CycleRecord::flags`]: the loop found the stop flag (a signal) set in this cycle.
pub const STOP_ASKED: u8 = 2;

/// Why bytes could not be encoded or decoded.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum FormatError {
    /// The output buffer is full.
    Full,
    /// The input ended inside a value.
    Truncated,
    /// A value that no encoder writes (a corrupt file or another format).
    Invalid(&'static str),
}

impl core::fmt::Display for FormatError {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        match self {
            FormatError::Full => f.write_str("the record does not fit its buffer"),
            FormatError::Truncated => f.write_str("the recording ends inside a record"),
            FormatError::Invalid(what) => write!(f, "invalid {what}"),
        }
    }
}

/// Writes into a fixed buffer; never allocates.
pub struct Out<'a> {
    buf: &'a mut [u8],
    len: usize,
}

impl<'a> Out<'a> {
    /// An empty output over `buf`.
    pub fn new(buf: &'a mut [u8]) -> Out<'a> {
        Out { buf, len: 0 }
    }
    /// Bytes written.
    pub fn len(&self) -> usize {
        self.len
    }
    /// Nothing written yet.
    pub fn is_empty(&self) -> bool {
        self.len == 0
    }
    /// The bytes written.
    pub fn written(&self) -> &[u8] {
        &self.buf[..self.len]
    }
    /// Appends bytes.
    pub fn bytes(&mut self, b: &[u8]) -> Result<(), FormatError> {
        let end = self.len + b.len();
        let dst = self.buf.get_mut(self.len..end).ok_or(FormatError::Full)?;
        dst.copy_from_slice(b);
        self.len = end;
        Ok(())
    }
    /// Appends one byte.
    pub fn u8(&mut self, v: u8) -> Result<(), FormatError> {
        self.bytes(&[v])
    }
    /// Appends an unsigned varint.
    pub fn uv(&mut self, mut v: u64) -> Result<(), FormatError> {
        loop {
            let b = (v & 0x7F) as u8;
            v >>= 7;
            if v == 0 {
                return self.u8(b);
            }
            self.u8(b | 0x80)?;
        }
    }
    /// Appends a signed varint (zigzag).
    pub fn sv(&mut self, v: i64) -> Result<(), FormatError> {
        self.uv(((v << 1) ^ (v >> 63)) as u64)
    }
    /// Appends a length-prefixed string.
    pub fn text(&mut self, s: &str) -> Result<(), FormatError> {
        self.uv(s.len() as u64)?;
        self.bytes(s.as_bytes())
    }
}

/// Reads from a byte slice.
#[derive(Debug, Clone)]
pub struct In<'a> {
    buf: &'a [u8],
    pos: usize,
}

impl<'a> In<'a> {
    /// A reader at the start of `buf`.
    pub fn new(buf: &'a [u8]) -> In<'a> {
        In { buf, pos: 0 }
    }
    /// Bytes left.
    pub fn remaining(&self) -> usize {
        self.buf.len() - self.pos
    }
    /// `n` bytes.
    pub fn bytes(&mut self, n: usize) -> Result<&'a [u8], FormatError> {
        let end = self.pos.checked_add(n).ok_or(FormatError::Truncated)?;
        let b = self.buf.get(self.pos..end).ok_or(FormatError::Truncated)?;
        self.pos = end;
        Ok(b)
    }
    /// One byte.
    pub fn u8(&mut self) -> Result<u8, FormatError> {
        Ok(self.bytes(1)?[0])
    }
    /// An unsigned varint.
    pub fn uv(&mut self) -> Result<u64, FormatError> {
        let mut v = 0u64;
        for shift in (0..64).step_by(7) {
            let b = self.u8()?;
            v |= u64::from(b & 0x7F) << shift;
            if b & 0x80 == 0 {
                return Ok(v);
            }
        }
        Err(FormatError::Invalid("varint"))
    }
    /// A signed varint (zigzag).
    pub fn sv(&mut self) -> Result<i64, FormatError> {
        let u = self.uv()?;
        Ok((u >> 1) as i64 ^ -((u & 1) as i64))
    }
    /// An unsigned varint that must fit `T`.
    pub fn uv_as<T: TryFrom<u64>>(&mut self, what: &'static str) -> Result<T, FormatError> {
        T::try_from(self.uv()?).map_err(|_| FormatError::Invalid(what))
    }
    /// A length-prefixed string.
    pub fn text(&mut self) -> Result<&'a str, FormatError> {
        let n = self.uv_as::<usize>("text length")?;
        core::str::from_utf8(self.bytes(n)?).map_err(|_| FormatError::Invalid("text"))
    }
}

/// What the recording's header holds: everything the replay needs to build the same cycle.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Header {
    /// The coordinator that recorded (its version), for the reader's messages.
    pub recorder: String,
    /// The machine's configuration, as the run read it.
    pub config: String,
    /// Virtual time (`true`) or real time.
    pub virtual_time: bool,
    /// The first cycle's time, ns.
    pub start_ns: u64,
    /// The run's own end (`--duration` in real time), ns after the start; virtual time ends
    /// from outside the loop (recorded per cycle).
    pub duration_ns: Option<u64>,
    /// The demonstration script's options: demo, chains, home.
    pub script: [bool; 3],
    /// `size_of::<MachineState>()` and the contract's layout hash when recorded.
    pub state_size: u32,
    /// The shared-memory contract's layout hash.
    pub layout_hash: u32,
}

impl Header {
    /// Encodes the header.
    pub fn encode(&self, o: &mut Vec<u8>) {
        let mut buf = vec![0u8; self.config.len() + self.recorder.len() + 128];
        let mut out = Out::new(&mut buf);
        // Sized above for every field: cannot be full.
        let _ = (|| -> Result<(), FormatError> {
            out.uv(u64::from(VERSION))?;
            out.text(&self.recorder)?;
            out.text(&self.config)?;
            out.u8(u8::from(self.virtual_time))?;
            out.uv(self.start_ns)?;
            out.uv(self.duration_ns.map_or(0, |d| d + 1))?;
            let s = &self.script;
            out.u8(u8::from(s[0]) | u8::from(s[1]) << 1 | u8::from(s[2]) << 2)?;
            out.uv(u64::from(self.state_size))?;
            out.bytes(&self.layout_hash.to_le_bytes())
        })();
        o.extend_from_slice(out.written());
    }

    /// Decodes a header.
    pub fn decode(i: &mut In<'_>) -> Result<Header, FormatError> {
        let v = i.uv()?;
        if v != u64::from(VERSION) {
            return Err(FormatError::Invalid("format version"));
        }
        let recorder = i.text()?.to_string();
        let config = i.text()?.to_string();
        let virtual_time = i.u8()? != 0;
        let start_ns = i.uv()?;
        let d = i.uv()?;
        let s = i.u8()?;
        let state_size = i.uv_as("state size")?;
        let h = i.bytes(4)?;
        Ok(Header {
            recorder,
            config,
            virtual_time,
            start_ns,
            duration_ns: d.checked_sub(1),
            script: [s & 1 != 0, s & 2 != 0, s & 4 != 0],
            state_size,
            layout_hash: u32::from_le_bytes([h[0], h[1], h[2], h[3]]),
        })
    }
}

/// One cycle: the inputs in the order the loop took them, and its outputs. Fixed capacities,
/// filled on the cycle thread without allocating.
#[derive(Debug, Clone)]
pub struct CycleRecord {
    /// [`ENDING_BEFORE`], [`STOP_ASKED`].
    pub flags: u8,
    /// The wake-up.
    pub wake: Wake,
    /// Frames received, in the order handed to the cycle.
    pub rx: Vec<BusFrame>,
    /// Drive reports: the axis and what it means.
    pub reports: Vec<(u16, NodeStatus)>,
    /// Modbus inputs, one per slot, in slot order.
    pub modbus_in: Vec<ImageInput>,
    /// Client requests.
    pub requests: Vec<Request>,
    /// The boot's SDO/NMT frames as the loop took them.
    pub service: Vec<BusFrame>,
    /// Frames sent, each with whether the bus took it (an input: a refusal is counted).
    pub sent: Vec<(BusFrame, bool)>,
    /// Answers: the request's tag and the reply in words.
    pub answers: Vec<(u64, heapless::String<96>)>,
    /// Modbus outputs, one per slot.
    pub modbus_out: Vec<Image>,
    /// More arrived than the record has room for (not encoded: such a record is not written).
    pub overflow: bool,
}

/// Capacities a [`CycleRecord`] is allocated with (the cycle's own bounds).
pub const MAX_REQUESTS: usize = 256;

impl CycleRecord {
    /// An empty record with room for one cycle's worth of everything.
    pub fn with_capacity(rx: usize, tx: usize, modbus: usize) -> CycleRecord {
        CycleRecord {
            flags: 0,
            wake: Wake {
                now: Instant::ZERO,
                late_ns: 0,
                skipped: 0,
            },
            rx: Vec::with_capacity(rx),
            reports: Vec::with_capacity(64),
            modbus_in: Vec::with_capacity(modbus),
            requests: Vec::with_capacity(MAX_REQUESTS),
            service: Vec::with_capacity(64),
            sent: Vec::with_capacity(tx + 64),
            answers: Vec::with_capacity(MAX_REQUESTS),
            modbus_out: Vec::with_capacity(modbus),
            overflow: false,
        }
    }

    /// Empties it for the next cycle (capacities kept).
    pub fn clear(&mut self) {
        self.flags = 0;
        self.overflow = false;
        self.rx.clear();
        self.reports.clear();
        self.modbus_in.clear();
        self.requests.clear();
        self.service.clear();
        self.sent.clear();
        self.answers.clear();
        self.modbus_out.clear();
    }

    /// Encodes the record; `prev_now` is the previous cycle's time (times are deltas).
    pub fn encode(&self, prev_now: Instant, o: &mut Out<'_>) -> Result<(), FormatError> {
        let now = self.wake.now;
        o.u8(self.flags)?;
        o.sv(now.as_nanos() as i64 - prev_now.as_nanos() as i64)?;
        o.uv(self.wake.late_ns)?;
        o.uv(self.wake.skipped)?;
        o.uv(self.rx.len() as u64)?;
        for f in &self.rx {
            frame(o, f, now)?;
        }
        o.uv(self.reports.len() as u64)?;
        for &(axis, s) in &self.reports {
            o.uv(u64::from(axis))?;
            o.u8(status_code(s))?;
        }
        o.uv(self.modbus_in.len() as u64)?;
        for m in &self.modbus_in {
            image(o, &m.image)?;
            // Bit 2: an EtherCAT subdevice's state and emergency follow (a Modbus image's
            // bytes are as before they existed).
            let ec = m.not_op != 0 || m.emcy != 0;
            o.u8(u8::from(m.fresh) | u8::from(m.lost) << 1 | u8::from(ec) << 2)?;
            o.uv(u64::from(m.late_cycles))?;
            if ec {
                o.u8(m.not_op)?;
                o.uv(u64::from(m.emcy))?;
            }
        }
        o.uv(self.requests.len() as u64)?;
        for r in &self.requests {
            o.uv(r.tag)?;
            command(o, &r.command)?;
        }
        o.uv(self.service.len() as u64)?;
        for f in &self.service {
            frame(o, f, now)?;
        }
        o.uv(self.sent.len() as u64)?;
        for (f, ok) in &self.sent {
            frame(o, f, now)?;
            o.u8(u8::from(*ok))?;
        }
        o.uv(self.answers.len() as u64)?;
        for (tag, text) in &self.answers {
            o.uv(*tag)?;
            o.text(text)?;
        }
        o.uv(self.modbus_out.len() as u64)?;
        for m in &self.modbus_out {
            image(o, m)?;
        }
        Ok(())
    }

    /// Decodes a record into `self` (cleared first).
    pub fn decode(&mut self, prev_now: Instant, i: &mut In<'_>) -> Result<(), FormatError> {
        self.clear();
        self.flags = i.u8()?;
        let now = prev_now
            .as_nanos()
            .checked_add_signed(i.sv()?)
            .ok_or(FormatError::Invalid("cycle time"))?;
        let now = Instant::from_nanos(now);
        self.wake = Wake {
            now,
            late_ns: i.uv()?,
            skipped: i.uv()?,
        };
        for _ in 0..i.uv()? {
            self.rx.push(read_frame(i, now)?);
        }
        for _ in 0..i.uv()? {
            let axis = i.uv_as("axis")?;
            self.reports.push((axis, status_of(i.u8()?)?));
        }
        for _ in 0..i.uv()? {
            let image = read_image(i)?;
            let b = i.u8()?;
            let late_cycles = i.uv_as("late cycles")?;
            let (not_op, emcy) = if b & 4 != 0 {
                (i.u8()?, i.uv_as("EMCY code")?)
            } else {
                (0, 0)
            };
            self.modbus_in.push(ImageInput {
                image,
                fresh: b & 1 != 0,
                lost: b & 2 != 0,
                late_cycles,
                not_op,
                emcy,
            });
        }
        for _ in 0..i.uv()? {
            let tag = i.uv()?;
            self.requests.push(Request {
                tag,
                command: read_command(i)?,
            });
        }
        for _ in 0..i.uv()? {
            self.service.push(read_frame(i, now)?);
        }
        for _ in 0..i.uv()? {
            let f = read_frame(i, now)?;
            self.sent.push((f, i.u8()? != 0));
        }
        for _ in 0..i.uv()? {
            let tag = i.uv()?;
            let mut s = heapless::String::new();
            s.push_str(i.text()?)
                .map_err(|_| FormatError::Invalid("answer"))?;
            self.answers.push((tag, s));
        }
        for _ in 0..i.uv()? {
            self.modbus_out.push(read_image(i)?);
        }
        Ok(())
    }
}

fn status_code(s: NodeStatus) -> u8 {
    match s {
        NodeStatus::Running => 0,
        NodeStatus::Waiting => 1,
        NodeStatus::Reset => 2,
        NodeStatus::Refused => 3,
    }
}

fn status_of(b: u8) -> Result<NodeStatus, FormatError> {
    Ok(match b {
        0 => NodeStatus::Running,
        1 => NodeStatus::Waiting,
        2 => NodeStatus::Reset,
        3 => NodeStatus::Refused,
        _ => return Err(FormatError::Invalid("drive report")),
    })
}

/// A frame: flags (extended, remote), identifier, length, the bytes the wire carried, and its
/// timestamp relative to the cycle's time.
fn frame(o: &mut Out<'_>, f: &BusFrame, now: Instant) -> Result<(), FormatError> {
    let fr = &f.frame;
    o.u8(f.bus)?;
    o.u8(u8::from(fr.is_extended()) | u8::from(fr.is_remote()) << 1)?;
    o.uv(u64::from(fr.raw_id()))?;
    o.u8(fr.dlc())?;
    if !fr.is_remote() {
        o.bytes(fr.data())?;
    }
    o.sv(fr.timestamp().as_nanos() as i64 - now.as_nanos() as i64)
}

fn read_frame(i: &mut In<'_>, now: Instant) -> Result<BusFrame, FormatError> {
    let bus = i.u8()?;
    let flags = i.u8()?;
    let raw: u32 = i.uv_as("identifier")?;
    let dlc = i.u8()?;
    let id = if flags & 1 != 0 {
        Id::Extended(ExtendedId::new(raw).ok_or(FormatError::Invalid("identifier"))?)
    } else {
        let raw = u16::try_from(raw).map_err(|_| FormatError::Invalid("identifier"))?;
        Id::Standard(StandardId::new(raw).ok_or(FormatError::Invalid("identifier"))?)
    };
    let f = if flags & 2 != 0 {
        Frame::new_remote(id, dlc)
    } else {
        Frame::new_data(id, i.bytes(usize::from(dlc))?)
    }
    .map_err(|_| FormatError::Invalid("frame"))?;
    let t = now
        .as_nanos()
        .checked_add_signed(i.sv()?)
        .ok_or(FormatError::Invalid("frame time"))?;
    Ok(BusFrame::new(bus, f.with_timestamp(Instant::from_nanos(t))))
}

fn image(o: &mut Out<'_>, m: &Image) -> Result<(), FormatError> {
    o.u8(m.len)?;
    o.bytes(m.bytes())
}

fn read_image(i: &mut In<'_>) -> Result<Image, FormatError> {
    let len = i.u8()?;
    if usize::from(len) > IMAGE_BYTES {
        return Err(FormatError::Invalid("image length"));
    }
    Image::from_slice(i.bytes(usize::from(len))?).ok_or(FormatError::Invalid("image"))
}

fn target(o: &mut Out<'_>, t: &Target) -> Result<(), FormatError> {
    match *t {
        Target::Axis(a) => {
            o.u8(0)?;
            o.uv(u64::from(a))
        }
        Target::Group(g) => {
            o.u8(1)?;
            o.uv(u64::from(g))
        }
        Target::All => o.u8(2),
    }
}

fn read_target(i: &mut In<'_>) -> Result<Target, FormatError> {
    Ok(match i.u8()? {
        0 => Target::Axis(i.uv_as("axis")?),
        1 => Target::Group(i.uv_as("group")?),
        2 => Target::All,
        _ => return Err(FormatError::Invalid("target")),
    })
}

fn buffer(b: BufferMode) -> u8 {
    match b {
        BufferMode::Aborting => 0,
        BufferMode::Buffered => 1,
    }
}

fn read_buffer(i: &mut In<'_>) -> Result<BufferMode, FormatError> {
    Ok(match i.u8()? {
        0 => BufferMode::Aborting,
        1 => BufferMode::Buffered,
        _ => return Err(FormatError::Invalid("buffer mode")),
    })
}

/// A command: a kind byte, then its fields in declaration order.
fn command(o: &mut Out<'_>, c: &Command) -> Result<(), FormatError> {
    match *c {
        Command::Enable(t) => {
            o.u8(1)?;
            target(o, &t)
        }
        Command::Disable(t) => {
            o.u8(2)?;
            target(o, &t)
        }
        Command::Acknowledge(t) => {
            o.u8(3)?;
            target(o, &t)
        }
        Command::Home(t) => {
            o.u8(4)?;
            target(o, &t)
        }
        Command::Jog { axis, permille } => {
            o.u8(5)?;
            o.uv(u64::from(axis))?;
            o.sv(i64::from(permille))
        }
        Command::MoveAxis {
            axis,
            position,
            velocity_percent,
            buffer: b,
        } => {
            o.u8(6)?;
            o.uv(u64::from(axis))?;
            o.sv(position)?;
            o.u8(velocity_percent)?;
            o.u8(buffer(b))
        }
        Command::MoveGroup {
            group,
            positions,
            velocity_percent,
            buffer: b,
        } => {
            o.u8(7)?;
            o.uv(u64::from(group))?;
            for p in positions {
                o.sv(p)?;
            }
            o.u8(velocity_percent)?;
            o.u8(buffer(b))
        }
        Command::StartChain { group, record } => {
            o.u8(8)?;
            o.uv(u64::from(group))?;
            o.uv(u64::from(record))
        }
        Command::Hold(t) => {
            o.u8(9)?;
            target(o, &t)
        }
        Command::Resume(t) => {
            o.u8(10)?;
            target(o, &t)
        }
        Command::Stop(t) => {
            o.u8(11)?;
            target(o, &t)
        }
        Command::QuickStop(t) => {
            o.u8(12)?;
            target(o, &t)
        }
        Command::SetOverride { target: t, percent } => {
            o.u8(13)?;
            target(o, &t)?;
            o.uv(u64::from(percent))
        }
        Command::ReadParameter { axis, pnu, sub } => {
            o.u8(14)?;
            o.uv(u64::from(axis))?;
            o.uv(u64::from(pnu))?;
            o.u8(sub)
        }
        Command::WriteParameter {
            axis,
            pnu,
            sub,
            value,
        } => {
            o.u8(15)?;
            o.uv(u64::from(axis))?;
            o.uv(u64::from(pnu))?;
            o.u8(sub)?;
            o.uv(u64::from(value))
        }
        Command::SetInput { bit, value } => {
            o.u8(16)?;
            o.u8(bit)?;
            o.u8(u8::from(value))
        }
    }
}

fn read_command(i: &mut In<'_>) -> Result<Command, FormatError> {
    Ok(match i.u8()? {
        1 => Command::Enable(read_target(i)?),
        2 => Command::Disable(read_target(i)?),
        3 => Command::Acknowledge(read_target(i)?),
        4 => Command::Home(read_target(i)?),
        5 => Command::Jog {
            axis: i.uv_as("axis")?,
            permille: i16::try_from(i.sv()?).map_err(|_| FormatError::Invalid("jog"))?,
        },
        6 => Command::MoveAxis {
            axis: i.uv_as("axis")?,
            position: i.sv()?,
            velocity_percent: i.u8()?,
            buffer: read_buffer(i)?,
        },
        7 => {
            let group = i.uv_as("group")?;
            let mut positions = [0i64; MAX_GROUP_AXES];
            for p in &mut positions {
                *p = i.sv()?;
            }
            Command::MoveGroup {
                group,
                positions,
                velocity_percent: i.u8()?,
                buffer: read_buffer(i)?,
            }
        }
        8 => Command::StartChain {
            group: i.uv_as("group")?,
            record: i.uv_as("record")?,
        },
        9 => Command::Hold(read_target(i)?),
        10 => Command::Resume(read_target(i)?),
        11 => Command::Stop(read_target(i)?),
        12 => Command::QuickStop(read_target(i)?),
        13 => Command::SetOverride {
            target: read_target(i)?,
            percent: i.uv_as("override")?,
        },
        14 => Command::ReadParameter {
            axis: i.uv_as("axis")?,
            pnu: i.uv_as("PNU")?,
            sub: i.u8()?,
        },
        15 => Command::WriteParameter {
            axis: i.uv_as("axis")?,
            pnu: i.uv_as("PNU")?,
            sub: i.u8()?,
            value: i.uv_as("parameter value")?,
        },
        16 => Command::SetInput {
            bit: i.u8()?,
            value: i.u8()? != 0,
        },
        _ => return Err(FormatError::Invalid("command")),
    })
}

/// A reply in words, as the record keeps it ("latched in cycle 812", "refused: busy").
pub fn reply_text(r: &Reply) -> heapless::String<96> {
    use core::fmt::Write;
    let mut s = heapless::String::new();
    // A reply's words fit 96 bytes (the longest is a wrong-state reason); a longer one is cut.
    let _ = match r {
        Reply::Latched { cycle } => write!(s, "latched in cycle {cycle}"),
        Reply::Rejected(why) => write!(s, "refused: {}", Rejected::clone(why)),
    };
    s
}

/// A frame in the words of a candump line: `bus 0 201#0102030405060708` (remote: `#R8`).
pub fn frame_text(f: &BusFrame) -> String {
    let fr = &f.frame;
    let id = if fr.is_extended() {
        format!("{:08X}", fr.raw_id())
    } else {
        format!("{:03X}", fr.raw_id())
    };
    if fr.is_remote() {
        format!("bus {} {id}#R{}", f.bus, fr.dlc())
    } else {
        let data: String = fr.data().iter().map(|b| format!("{b:02X}")).collect();
        format!("bus {} {id}#{data}", f.bus)
    }
}

/// The published state as the difference from the previous one: runs of
/// `(unchanged bytes, changed bytes, the XOR of the changed bytes)`, varints; nearly all of a
/// state is unchanged from one cycle to the next. `prev` and `next` have the same length.
pub fn delta(prev: &[u8], next: &[u8], o: &mut Vec<u8>) {
    let put = put_uv;
    let n = prev.len().min(next.len());
    let mut i = 0;
    while i < n {
        let start = i;
        while i < n && prev[i] == next[i] {
            i += 1;
        }
        if i == n {
            break;
        }
        let same = i - start;
        let from = i;
        // A changed run ends at 4 equal bytes in a row (fewer cost less inline).
        while i < n && prev[i..(i + 4).min(n)] != next[i..(i + 4).min(n)] {
            i += 1;
        }
        put(same as u64, o);
        put((i - from) as u64, o);
        o.extend(prev[from..i].iter().zip(&next[from..i]).map(|(a, b)| a ^ b));
    }
}

/// Appends one cycle to a recording's stream (before compression): the encoded record, then
/// the state as its [`delta`] from `prev` (which becomes `state`), each length-prefixed.
pub fn append_cycle(
    o: &mut Vec<u8>,
    record: &[u8],
    prev: &mut [u8],
    state: &[u8],
    d: &mut Vec<u8>,
) {
    put_uv(record.len() as u64, o);
    o.extend_from_slice(record);
    d.clear();
    delta(prev, state, d);
    put_uv(d.len() as u64, o);
    o.extend_from_slice(d);
    prev.copy_from_slice(state);
}

/// Reads one cycle of a recording's stream: decodes its record into `record` and applies its
/// state delta to `state`. `prev_now` is the previous cycle's time.
pub fn read_cycle(
    i: &mut In<'_>,
    prev_now: Instant,
    record: &mut CycleRecord,
    state: &mut [u8],
) -> Result<(), FormatError> {
    let n: usize = i.uv_as("record length")?;
    let mut r = In::new(i.bytes(n)?);
    record.decode(prev_now, &mut r)?;
    let n: usize = i.uv_as("state length")?;
    undelta(state, i.bytes(n)?)
}

/// Appends an unsigned varint to a vector (the writer's side; the cycle uses [`Out`]).
pub fn put_uv(mut v: u64, o: &mut Vec<u8>) {
    loop {
        let b = (v & 0x7F) as u8;
        v >>= 7;
        if v == 0 {
            o.push(b);
            return;
        }
        o.push(b | 0x80);
    }
}

/// Applies a [`delta`] to `state` (the previous state becomes the next).
pub fn undelta(state: &mut [u8], d: &[u8]) -> Result<(), FormatError> {
    let mut i = In::new(d);
    let mut at = 0usize;
    while i.remaining() > 0 {
        at = at
            .checked_add(i.uv_as::<usize>("state delta")?)
            .ok_or(FormatError::Invalid("state delta"))?;
        let n = i.uv_as::<usize>("state delta")?;
        let x = i.bytes(n)?;
        let dst = state
            .get_mut(at..at + n)
            .ok_or(FormatError::Invalid("state delta"))?;
        for (d, x) in dst.iter_mut().zip(x) {
            *d ^= x;
        }
        at += n;
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    fn sample() -> CycleRecord {
        let mut r = CycleRecord::with_capacity(8, 8, 2);
        r.flags = STOP_ASKED;
        r.wake = Wake {
            now: Instant::from_nanos(5_000_000),
            late_ns: 1234,
            skipped: 1,
        };
        let f = Frame::new_std(0x181, &[1, 2, 3]).unwrap();
        r.rx.push(BusFrame::new(
            1,
            f.with_timestamp(Instant::from_nanos(4_990_000)),
        ));
        let e = Frame::new_ext(0x1ABC_DEF0, &[]).unwrap();
        r.rx.push(BusFrame::new(
            0,
            e.with_timestamp(Instant::from_nanos(5_000_001)),
        ));
        let rtr = Frame::new_std_remote(0x701, 1).unwrap();
        r.rx.push(BusFrame::new(0, rtr));
        r.reports.push((3, NodeStatus::Reset));
        r.modbus_in.push(ImageInput {
            image: Image::from_slice(&[1, 2, 3, 4, 5, 6, 7, 8]).unwrap(),
            fresh: true,
            late_cycles: 2,
            lost: false,
            ..ImageInput::default()
        });
        r.modbus_in.push(ImageInput {
            image: Image::from_slice(&[0x13, 0x0D, 0, 0, 0, 0, 0, 0]).unwrap(),
            fresh: true,
            late_cycles: 0,
            lost: false,
            not_op: 4,
            emcy: 0x8100,
        });
        r.requests.push(Request {
            tag: 77,
            command: Command::MoveGroup {
                group: 1,
                positions: [1, -2, 3, -4, 5, -6, 7, i64::MIN],
                velocity_percent: 50,
                buffer: BufferMode::Buffered,
            },
        });
        r.requests.push(Request {
            tag: 78,
            command: Command::SetOverride {
                target: Target::All,
                percent: 150,
            },
        });
        r.service
            .push(BusFrame::new(0, Frame::std8(0x601, [0x40; 8])));
        r.sent
            .push((BusFrame::new(0, Frame::std8(0x80, [0; 8])), false));
        r.answers.push((
            77,
            reply_text(&Reply::Rejected(Rejected::WrongState("not homed"))),
        ));
        r.modbus_out.push(Image::from_slice(&[9, 9]).unwrap());
        r
    }

    fn same(a: &CycleRecord, b: &CycleRecord) {
        assert_eq!(a.flags, b.flags);
        assert_eq!(a.wake, b.wake);
        let frames = |v: &[BusFrame]| {
            v.iter()
                .map(|f| (f.bus, f.frame, f.frame.timestamp()))
                .collect::<Vec<_>>()
        };
        assert_eq!(frames(&a.rx), frames(&b.rx));
        assert_eq!(a.reports, b.reports);
        assert_eq!(a.modbus_in, b.modbus_in);
        assert_eq!(a.requests, b.requests);
        assert_eq!(frames(&a.service), frames(&b.service));
        assert_eq!(a.sent.len(), b.sent.len());
        assert_eq!(a.answers, b.answers);
        assert_eq!(a.modbus_out, b.modbus_out);
    }

    #[test]
    fn a_cycle_record_decodes_to_what_was_encoded() {
        let r = sample();
        let mut buf = [0u8; 1024];
        let mut o = Out::new(&mut buf);
        let prev = Instant::from_nanos(3_000_000);
        r.encode(prev, &mut o).unwrap();
        let n = o.len();
        let mut back = CycleRecord::with_capacity(8, 8, 2);
        let mut i = In::new(&buf[..n]);
        back.decode(prev, &mut i).unwrap();
        assert_eq!(i.remaining(), 0);
        same(&r, &back);
        assert_eq!(
            back.answers[0].1.as_str(),
            "refused: wrong state: not homed"
        );
    }

    #[test]
    fn a_full_buffer_and_a_cut_record_are_errors_not_panics() {
        let r = sample();
        let mut small = [0u8; 20];
        assert_eq!(
            r.encode(Instant::ZERO, &mut Out::new(&mut small)),
            Err(FormatError::Full)
        );
        let mut buf = [0u8; 1024];
        let mut o = Out::new(&mut buf);
        r.encode(Instant::ZERO, &mut o).unwrap();
        let n = o.len();
        let mut back = CycleRecord::with_capacity(8, 8, 2);
        for cut in 0..n {
            assert!(
                back.decode(Instant::ZERO, &mut In::new(&buf[..cut]))
                    .is_err()
            );
        }
    }

    #[test]
    fn the_header_round_trips() {
        let h = Header {
            recorder: "coordinator 0.1.0".into(),
            config: "[machine]\ncycle_us = 2000\n".into(),
            virtual_time: true,
            start_ns: 1_000_000,
            duration_ns: Some(0),
            script: [true, false, true],
            state_size: 17248,
            layout_hash: 0xad80_69d3,
        };
        let mut v = Vec::new();
        h.encode(&mut v);
        assert_eq!(Header::decode(&mut In::new(&v)).unwrap(), h);
        let none = Header {
            duration_ns: None,
            ..h
        };
        let mut v = Vec::new();
        none.encode(&mut v);
        assert_eq!(Header::decode(&mut In::new(&v)).unwrap(), none);
    }

    #[test]
    fn a_state_delta_rebuilds_the_next_state() {
        let prev: Vec<u8> = (0..1000u32).map(|i| (i * 7) as u8).collect();
        let mut next = prev.clone();
        next[0] ^= 1;
        next[10..14].copy_from_slice(&[0, 0, 0, 0]);
        next[999] = 42;
        let mut d = Vec::new();
        delta(&prev, &next, &mut d);
        assert!(d.len() < 30, "{} bytes", d.len());
        let mut s = prev.clone();
        undelta(&mut s, &d).unwrap();
        assert_eq!(s, next);
        let mut d = Vec::new();
        delta(&prev, &prev, &mut d);
        assert!(d.is_empty());
    }
}
