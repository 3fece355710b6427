//! The SDO server: the device side of one node's default SDO channel (600h/580h + node).

use core::time::Duration;

use heapless::Deque;

use super::AbortedBy;
use super::codec::{
    BlockSegment, ClientFrame, InitiateData, SEGMENT_DATA, Segment, ServerFrame, frame_bytes,
    is_block_abort,
};
use super::crc::{crc16, crc16_update};
use crate::can::Frame;
use crate::canopen::od::ObjectAccess;
use crate::canopen::{AbortCode, Address, NodeId, ids};
use crate::time::Instant;

/// How an [`SdoServer`] behaves.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct SdoServerConfig {
    /// Silence from the client longer than this aborts the transfer with 0504 0000h.
    pub timeout: Duration,
    /// The block size (segments per sub-block, 1..=127) the server proposes for block
    /// downloads. Values outside the range are clamped.
    pub block_size: u8,
    /// In a block download, silence this long within a sub-block makes the server acknowledge
    /// what it has (the client then resends the rest) instead of waiting for the full timeout.
    /// This recovers a lost last segment of a sub-block.
    pub sub_block_timeout: Duration,
    /// Whether the server generates and checks block-transfer CRCs (`sc`).
    pub crc: bool,
}

impl Default for SdoServerConfig {
    fn default() -> Self {
        SdoServerConfig {
            timeout: Duration::from_millis(500),
            block_size: 127,
            sub_block_timeout: Duration::from_millis(100),
            crc: true,
        }
    }
}

/// What happened at an [`SdoServer`], for the device application and for logs.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum ServerEvent {
    /// A download completed: the value was written to the dictionary.
    Downloaded {
        /// The object written.
        addr: Address,
        /// Its length in bytes.
        len: usize,
    },
    /// An upload completed.
    Uploaded {
        /// The object read.
        addr: Address,
        /// Bytes transferred.
        len: usize,
    },
    /// A transfer ended with an abort, sent by the server or received from the client.
    Aborted {
        /// The object of the transfer (as the abort frame names it).
        addr: Address,
        /// Why.
        code: AbortCode,
        /// Who aborted.
        by: AbortedBy,
    },
    /// A frame on the server's COB-ID did not carry 8 bytes; it was ignored (CANopen servers
    /// commonly drop such frames; answering one could answer a frame of another protocol).
    Malformed {
        /// The frame's data length (0 for a remote frame).
        len: u8,
    },
}

/// The phase of a block upload.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum UpPhase {
    AwaitStart,
    Sending,
    AwaitAck,
    AwaitEnd,
}

#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum State {
    Idle,
    /// Segmented download; `len` bytes collected in the buffer.
    Download {
        addr: Address,
        toggle: bool,
        size: Option<u32>,
    },
    /// Segmented upload; `offset` bytes already sent.
    Upload {
        addr: Address,
        toggle: bool,
        offset: usize,
        size: usize,
    },
    /// Block download: receiving sub-blocks (`done` once the `c` segment was acknowledged,
    /// then the end frame is awaited).
    BlockDown {
        addr: Address,
        size: Option<u32>,
        crc: bool,
        expected: u8,
        done: bool,
        /// Bytes received in sequence, counting the last segment as 7.
        received: usize,
        /// Whether a segment arrived since the last acknowledge. Only then may the sub-block
        /// timer acknowledge: with nothing received, the server cannot tell whether its last
        /// acknowledge was lost (the client waits for it) or the new sub-block was (the client
        /// waits for an ack of that), and a guess would duplicate or skip data.
        seen: bool,
    },
    /// Block upload: the buffer holds the value's bytes `offset..offset + len` (the current
    /// sub-block, kept until acknowledged so a partial ackseq can be served again).
    BlockUp {
        addr: Address,
        size: usize,
        offset: usize,
        crc_on: bool,
        crc: u16,
        /// Bytes of the value read from the dictionary so far (and fed into `crc`).
        read: usize,
        blksize: u8,
        segs: u8,
        sent: u8,
        phase: UpPhase,
    },
}

/// The device side of SDO for one node: expedited, segmented and block transfer in both
/// directions, reading and writing through an [`ObjectAccess`].
///
/// `BUF` bounds a download (the whole value is collected, then written at once) and a block
/// upload's sub-block (`7 * blksize` bytes; 889 bytes allow every block size a client may ask).
///
/// Choices where CiA 301 leaves room:
/// - A frame that is not 8 bytes long is ignored and reported as [`ServerEvent::Malformed`].
/// - An initiate frame while a transfer runs starts the new transfer (the client gave up).
/// - Download sizes: announced above `BUF` -> 0504 0005h at the initiate; more data than
///   announced -> 0607 0012h; less -> 0607 0013h; more than `BUF` without size -> 0504 0005h.
/// - A download to a missing object is refused at the initiate with the dictionary's
///   0602 0000h / 0609 0011h, before any data crosses the bus.
/// - In a block download, out-of-sequence segments are dropped and the end of the sub-block
///   (seqno = blksize, or `c`) is acknowledged with the last good seqno; if the sub-block's
///   last segment itself is lost, [`SdoServerConfig::sub_block_timeout`] triggers that
///   acknowledge.
///
/// ```
/// use drivers::canopen::sdo::{SdoServer, SdoServerConfig};
/// use drivers::canopen::NodeId;
/// let server: SdoServer<1024> = SdoServer::new(NodeId::new(1).unwrap(), SdoServerConfig::default());
/// assert_eq!(server.node().get(), 1);
/// ```
#[derive(Debug)]
pub struct SdoServer<const BUF: usize> {
    node: NodeId,
    config: SdoServerConfig,
    state: State,
    buf: [u8; BUF],
    len: usize,
    last_rx: Instant,
    tx: Deque<Frame, 4>,
    events: Deque<ServerEvent, 8>,
    lost: u32,
}

impl<const BUF: usize> SdoServer<BUF> {
    /// A server for `node`.
    pub fn new(node: NodeId, mut config: SdoServerConfig) -> Self {
        config.block_size = config.block_size.clamp(1, super::codec::MAX_BLOCK_SIZE);
        SdoServer {
            node,
            config,
            state: State::Idle,
            buf: [0; BUF],
            len: 0,
            last_rx: Instant::ZERO,
            tx: Deque::new(),
            events: Deque::new(),
            lost: 0,
        }
    }

    /// The node this server serves.
    pub fn node(&self) -> NodeId {
        self.node
    }

    /// The configuration in use.
    pub fn config(&self) -> &SdoServerConfig {
        &self.config
    }

    /// Whether `frame` is addressed to this server (COB-ID 600h + node, standard identifier).
    pub fn accepts(&self, frame: &Frame) -> bool {
        frame.cob_id() == Some(ids::SDO_RX + self.node.get() as u16)
    }

    /// Whether no transfer is in progress.
    pub fn is_idle(&self) -> bool {
        self.state == State::Idle
    }

    /// Frames or events dropped because their queue was full (the caller polled too rarely).
    pub fn lost(&self) -> u32 {
        self.lost
    }

    /// Feeds one received frame. Frames for other COB-IDs are ignored. Replies go out through
    /// [`poll_transmit`](Self::poll_transmit).
    pub fn handle_frame(&mut self, frame: &Frame, now: Instant, od: &mut impl ObjectAccess) {
        if !self.accepts(frame) {
            return;
        }
        let b = match frame_bytes(frame) {
            Ok(b) => b,
            Err(_) => {
                self.event(ServerEvent::Malformed {
                    len: frame.data().len() as u8,
                });
                return;
            }
        };
        self.last_rx = now;
        if let State::BlockDown { done: false, .. } = self.state {
            if is_block_abort(&b) {
                if let Ok(ClientFrame::Abort { addr, code }) = ClientFrame::decode(&b) {
                    self.client_abort(addr, code);
                }
            } else {
                self.block_segment(&b);
            }
            return;
        }
        match ClientFrame::decode(&b) {
            Ok(f) => self.dispatch(f, now, od),
            Err(e) => self.abort(self.current_addr(), e.abort_code()),
        }
    }

    /// The next frame to send, if any. A block upload's sub-block comes out here one segment
    /// per call.
    pub fn poll_transmit(&mut self, now: Instant) -> Option<Frame> {
        if let Some(f) = self.tx.pop_front() {
            return Some(f);
        }
        let cob = self.cob();
        if let State::BlockUp {
            size,
            offset,
            segs,
            ref mut sent,
            ref mut phase,
            ..
        } = self.state
            && *phase == UpPhase::Sending
        {
            let start = *sent as usize * SEGMENT_DATA;
            let end = (start + SEGMENT_DATA).min(self.len);
            let chunk = self.buf.get(start..end).unwrap_or(&[]);
            *sent += 1;
            // The `c` bit marks the segment that reaches the end of the value.
            let last = end == self.len && offset + self.len >= size;
            if *sent >= segs {
                *phase = UpPhase::AwaitAck;
                // The client's silence counts from the last segment sent.
                self.last_rx = now;
            }
            return Some(Frame::std8(
                cob,
                BlockSegment::new(*sent, last, chunk).to_bytes(),
            ));
        }
        None
    }

    /// The next event, if any.
    pub fn poll_event(&mut self) -> Option<ServerEvent> {
        self.events.pop_front()
    }

    /// When [`handle_timeout`](Self::handle_timeout) must be called next, if a transfer waits
    /// for the client.
    pub fn poll_timeout(&self) -> Option<Instant> {
        match self.state {
            State::Idle => None,
            State::BlockUp {
                phase: UpPhase::Sending,
                ..
            } => None,
            State::BlockDown {
                done: false,
                seen: true,
                ..
            } => Some(self.last_rx + self.config.sub_block_timeout.min(self.config.timeout)),
            _ => Some(self.last_rx + self.config.timeout),
        }
    }

    /// Acts on the passage of time: acknowledges a stalled block-download sub-block, or aborts
    /// a transfer whose client went silent (0504 0000h).
    pub fn handle_timeout(&mut self, now: Instant) {
        let Some(deadline) = self.poll_timeout() else {
            return;
        };
        if now < deadline {
            return;
        }
        // A client silent for the whole SDO timeout has gone, even in the middle of a
        // sub-block: abort rather than acknowledge and wait once more.
        if let State::BlockDown {
            done: false,
            seen: true,
            expected,
            ..
        } = self.state
            && self.config.sub_block_timeout < self.config.timeout
            && now < self.last_rx + self.config.timeout
        {
            return self.ack_sub_block(expected - 1, false);
        }
        self.abort(self.current_addr(), AbortCode::Timeout);
    }

    fn cob(&self) -> u16 {
        ids::SDO_TX + self.node.get() as u16
    }

    fn current_addr(&self) -> Address {
        match self.state {
            State::Idle => Address::default(),
            State::Download { addr, .. }
            | State::Upload { addr, .. }
            | State::BlockDown { addr, .. }
            | State::BlockUp { addr, .. } => addr,
        }
    }

    fn send(&mut self, f: ServerFrame) {
        let frame = Frame::std8(self.cob(), f.to_bytes());
        if self.tx.is_full() {
            self.tx.pop_front();
            self.lost = self.lost.saturating_add(1);
        }
        let _ = self.tx.push_back(frame);
    }

    fn event(&mut self, e: ServerEvent) {
        if self.events.is_full() {
            self.events.pop_front();
            self.lost = self.lost.saturating_add(1);
        }
        let _ = self.events.push_back(e);
    }

    fn abort(&mut self, addr: Address, code: AbortCode) {
        self.send(ServerFrame::Abort { addr, code });
        self.event(ServerEvent::Aborted {
            addr,
            code,
            by: AbortedBy::Server,
        });
        self.reset();
    }

    fn client_abort(&mut self, addr: Address, code: AbortCode) {
        self.event(ServerEvent::Aborted {
            addr,
            code,
            by: AbortedBy::Client,
        });
        self.reset();
    }

    fn reset(&mut self) {
        self.state = State::Idle;
        self.len = 0;
    }

    /// Checks that an object exists before a download starts, so a missing object is refused
    /// at once rather than after the data crossed the bus.
    fn exists(od: &mut impl ObjectAccess, addr: Address) -> Result<(), AbortCode> {
        match od.size(addr) {
            Err(c @ (AbortCode::NoObject | AbortCode::NoSubIndex)) => Err(c),
            _ => Ok(()),
        }
    }

    fn dispatch(&mut self, f: ClientFrame, now: Instant, od: &mut impl ObjectAccess) {
        match (f, self.state) {
            (ClientFrame::Abort { addr, code }, _) => self.client_abort(addr, code),
            (ClientFrame::InitiateDownload { addr, data }, _) => {
                self.reset();
                self.initiate_download(addr, data, od);
            }
            (ClientFrame::InitiateUpload { addr }, _) => {
                self.reset();
                self.initiate_upload(addr, od);
            }
            (ClientFrame::BlockDownloadInitiate { addr, crc, size }, _) => {
                self.reset();
                if let Err(c) = Self::exists(od, addr) {
                    return self.abort(addr, c);
                }
                if size.is_some_and(|s| s as usize > BUF) {
                    return self.abort(addr, AbortCode::OutOfMemory);
                }
                self.state = State::BlockDown {
                    addr,
                    size,
                    crc: crc && self.config.crc,
                    expected: 1,
                    done: false,
                    received: 0,
                    seen: false,
                };
                self.send(ServerFrame::BlockDownloadInitiate {
                    addr,
                    crc: self.config.crc,
                    blksize: self.config.block_size,
                });
            }
            (
                ClientFrame::BlockUploadInitiate {
                    addr,
                    crc,
                    blksize,
                    pst,
                },
                _,
            ) => {
                self.reset();
                let size = match od.size(addr) {
                    Ok(s) => s,
                    Err(c) => return self.abort(addr, c),
                };
                if pst > 0 && size <= pst as usize {
                    // Protocol switch (CiA 301): a small value goes by the normal upload.
                    return self.initiate_upload(addr, od);
                }
                self.state = State::BlockUp {
                    addr,
                    size,
                    offset: 0,
                    crc_on: crc && self.config.crc,
                    crc: 0,
                    read: 0,
                    blksize,
                    segs: 0,
                    sent: 0,
                    phase: UpPhase::AwaitStart,
                };
                self.send(ServerFrame::BlockUploadInitiate {
                    addr,
                    crc: self.config.crc,
                    size: u32::try_from(size).ok(),
                });
            }
            (ClientFrame::DownloadSegment(seg), State::Download { addr, toggle, size }) => {
                self.download_segment(seg, addr, toggle, size, od);
            }
            (
                ClientFrame::UploadSegment { toggle: t },
                State::Upload {
                    addr,
                    toggle,
                    offset,
                    size,
                },
            ) => {
                if t != toggle {
                    return self.abort(addr, AbortCode::ToggleBit);
                }
                let mut chunk = [0u8; SEGMENT_DATA];
                let want = (size - offset).min(SEGMENT_DATA);
                let n = match Self::read_full(od, addr, offset, &mut chunk[..want]) {
                    Ok(n) => n,
                    Err(c) => return self.abort(addr, c),
                };
                let last = offset + n >= size;
                self.send(ServerFrame::UploadSegment(Segment::new(
                    toggle,
                    &chunk[..n],
                    last,
                )));
                if last {
                    self.event(ServerEvent::Uploaded { addr, len: size });
                    self.reset();
                } else {
                    self.state = State::Upload {
                        addr,
                        toggle: !toggle,
                        offset: offset + n,
                        size,
                    };
                }
            }
            (
                ClientFrame::BlockDownloadEnd { unused, crc },
                State::BlockDown {
                    addr,
                    size,
                    crc: crc_on,
                    done: true,
                    received,
                    ..
                },
            ) => {
                let Some(real) = received.checked_sub(unused as usize) else {
                    return self.abort(addr, AbortCode::TooShort);
                };
                if real > BUF {
                    return self.abort(addr, AbortCode::OutOfMemory);
                }
                if let Some(c) = Self::size_mismatch(size, real) {
                    return self.abort(addr, c);
                }
                if crc_on && crc16(&self.buf[..real]) != crc {
                    return self.abort(addr, AbortCode::CrcError);
                }
                match od.write(addr, &self.buf[..real]) {
                    Ok(()) => {
                        self.send(ServerFrame::BlockDownloadEnd);
                        self.event(ServerEvent::Downloaded { addr, len: real });
                        self.reset();
                    }
                    Err(c) => self.abort(addr, c),
                }
            }
            (
                ClientFrame::BlockUploadStart,
                State::BlockUp {
                    phase: UpPhase::AwaitStart,
                    ..
                },
            ) => {
                self.fill_sub_block(od, now);
            }
            (
                ClientFrame::BlockUploadAck { ackseq, blksize },
                State::BlockUp {
                    addr,
                    size,
                    offset,
                    segs,
                    crc_on,
                    crc,
                    phase: UpPhase::AwaitAck,
                    ..
                },
            ) => {
                if ackseq > segs {
                    return self.abort(addr, AbortCode::InvalidSequence);
                }
                let consumed = (ackseq as usize * SEGMENT_DATA).min(self.len);
                self.buf.copy_within(consumed..self.len, 0);
                self.len -= consumed;
                let offset = offset + consumed;
                if let State::BlockUp {
                    offset: ref mut o,
                    blksize: ref mut bs,
                    ..
                } = self.state
                {
                    *o = offset;
                    *bs = blksize;
                }
                if offset >= size && self.len == 0 && ackseq > 0 {
                    let total_segs = size.div_ceil(SEGMENT_DATA).max(1);
                    let unused = (total_segs * SEGMENT_DATA - size) as u8;
                    if let State::BlockUp { ref mut phase, .. } = self.state {
                        *phase = UpPhase::AwaitEnd;
                    }
                    self.send(ServerFrame::BlockUploadEnd {
                        unused,
                        crc: if crc_on { crc } else { 0 },
                    });
                } else {
                    self.fill_sub_block(od, now);
                }
            }
            (
                ClientFrame::BlockUploadEnd,
                State::BlockUp {
                    addr,
                    size,
                    phase: UpPhase::AwaitEnd,
                    ..
                },
            ) => {
                self.event(ServerEvent::Uploaded { addr, len: size });
                self.reset();
            }
            _ => self.abort(self.current_addr(), AbortCode::InvalidCommand),
        }
    }

    fn size_mismatch(size: Option<u32>, real: usize) -> Option<AbortCode> {
        let s = size? as usize;
        match real.cmp(&s) {
            core::cmp::Ordering::Less => Some(AbortCode::TooShort),
            core::cmp::Ordering::Greater => Some(AbortCode::TooLong),
            core::cmp::Ordering::Equal => None,
        }
    }

    fn initiate_download(&mut self, addr: Address, data: InitiateData, od: &mut impl ObjectAccess) {
        match data {
            InitiateData::Expedited { data, len } => {
                // Without size indication the object's own size tells how much is meant.
                let l = len
                    .map(usize::from)
                    .or_else(|| od.size(addr).ok().filter(|s| (1..=4).contains(s)))
                    .unwrap_or(4)
                    .min(4);
                match od.write(addr, &data[..l]) {
                    Ok(()) => {
                        self.send(ServerFrame::InitiateDownload { addr });
                        self.event(ServerEvent::Downloaded { addr, len: l });
                    }
                    Err(c) => self.abort(addr, c),
                }
            }
            InitiateData::Segmented { size } => {
                if let Err(c) = Self::exists(od, addr) {
                    return self.abort(addr, c);
                }
                if size.is_some_and(|s| s as usize > BUF) {
                    return self.abort(addr, AbortCode::OutOfMemory);
                }
                self.state = State::Download {
                    addr,
                    toggle: false,
                    size,
                };
                self.send(ServerFrame::InitiateDownload { addr });
            }
        }
    }

    fn download_segment(
        &mut self,
        seg: Segment,
        addr: Address,
        toggle: bool,
        size: Option<u32>,
        od: &mut impl ObjectAccess,
    ) {
        if seg.toggle != toggle {
            return self.abort(addr, AbortCode::ToggleBit);
        }
        let p = seg.payload();
        let new_len = self.len + p.len();
        if size.is_some_and(|s| new_len > s as usize) {
            return self.abort(addr, AbortCode::TooLong);
        }
        if new_len > BUF {
            return self.abort(addr, AbortCode::OutOfMemory);
        }
        self.buf[self.len..new_len].copy_from_slice(p);
        self.len = new_len;
        if !seg.last {
            self.state = State::Download {
                addr,
                toggle: !toggle,
                size,
            };
            self.send(ServerFrame::DownloadSegment { toggle });
            return;
        }
        if let Some(c) = Self::size_mismatch(size, new_len) {
            return self.abort(addr, c);
        }
        match od.write(addr, &self.buf[..new_len]) {
            Ok(()) => {
                self.send(ServerFrame::DownloadSegment { toggle });
                self.event(ServerEvent::Downloaded { addr, len: new_len });
                self.reset();
            }
            Err(c) => self.abort(addr, c),
        }
    }

    fn initiate_upload(&mut self, addr: Address, od: &mut impl ObjectAccess) {
        let size = match od.size(addr) {
            Ok(s) => s,
            Err(c) => return self.abort(addr, c),
        };
        if (1..=4).contains(&size) {
            let mut d = [0u8; 4];
            match Self::read_full(od, addr, 0, &mut d[..size]) {
                Ok(n) if n == size => {
                    self.send(ServerFrame::InitiateUpload {
                        addr,
                        data: InitiateData::Expedited {
                            data: d,
                            len: Some(size as u8),
                        },
                    });
                    self.event(ServerEvent::Uploaded { addr, len: size });
                }
                Ok(_) => self.abort(addr, AbortCode::General),
                Err(c) => self.abort(addr, c),
            }
            return;
        }
        let Ok(s32) = u32::try_from(size) else {
            return self.abort(addr, AbortCode::TooLong);
        };
        self.state = State::Upload {
            addr,
            toggle: false,
            offset: 0,
            size,
        };
        self.send(ServerFrame::InitiateUpload {
            addr,
            data: InitiateData::Segmented { size: Some(s32) },
        });
    }

    /// Reads until `buf` is full; a dictionary that returns 0 bytes early has less data than it
    /// announced, which is its error (0800 0024h, no data available).
    fn read_full(
        od: &mut impl ObjectAccess,
        addr: Address,
        offset: usize,
        buf: &mut [u8],
    ) -> Result<usize, AbortCode> {
        let mut done = 0;
        while done < buf.len() {
            let n = od.read(addr, offset + done, &mut buf[done..])?;
            if n == 0 {
                return Err(AbortCode::NoData);
            }
            done += n.min(buf.len() - done);
        }
        Ok(done)
    }

    /// Tops up the buffer to the next sub-block and starts sending it.
    fn fill_sub_block(&mut self, od: &mut impl ObjectAccess, now: Instant) {
        let State::BlockUp {
            addr,
            size,
            offset,
            blksize,
            read,
            crc,
            ..
        } = self.state
        else {
            return;
        };
        let want = (blksize as usize * SEGMENT_DATA).min(size - offset);
        if want > BUF {
            return self.abort(addr, AbortCode::OutOfMemory);
        }
        // Bytes offset..offset+len are already buffered (unacknowledged), the rest is new.
        let have = self.len;
        if want > have {
            let fresh_at = offset + have;
            match Self::read_full(od, addr, fresh_at, &mut self.buf[have..want]) {
                Ok(_) => {}
                Err(c) => return self.abort(addr, c),
            }
            // Every byte is read from the dictionary once (resent segments come from the
            // buffer), so the CRC runs as the value is read.
            debug_assert_eq!(fresh_at, read);
            let new_crc = crc16_update(crc, &self.buf[have..want]);
            self.len = want;
            if let State::BlockUp {
                crc: ref mut c,
                read: ref mut r,
                ..
            } = self.state
            {
                *c = new_crc;
                *r = offset + want;
            }
        }
        // After the client shrank its block size, unacknowledged data may exceed one sub-block;
        // the rest waits in the buffer for the next one.
        let segs = self.len.div_ceil(SEGMENT_DATA).clamp(1, blksize as usize) as u8;
        if let State::BlockUp {
            segs: ref mut s,
            ref mut sent,
            ref mut phase,
            ..
        } = self.state
        {
            *s = segs;
            *sent = 0;
            *phase = UpPhase::Sending;
        }
        self.last_rx = now;
    }

    fn block_segment(&mut self, b: &[u8; 8]) {
        let State::BlockDown {
            addr,
            size,
            expected,
            received,
            ..
        } = self.state
        else {
            return;
        };
        let seg = match BlockSegment::decode(b) {
            Ok(s) => s,
            Err(e) => return self.abort(addr, e.abort_code()),
        };
        if let State::BlockDown { ref mut seen, .. } = self.state {
            *seen = true;
        }
        let blksize = self.config.block_size;
        let ends_sub_block = seg.last || seg.seqno >= blksize;
        if seg.seqno != expected {
            // Out of sequence: drop it; at the end of the sub-block acknowledge the last good
            // segment, and the client resends from there (CiA 301 block download).
            if ends_sub_block {
                self.ack_sub_block(expected - 1, false);
            }
            return;
        }
        // The first segment is always due (an empty value still takes one).
        if received > 0 && size.is_some_and(|s| received >= s as usize) {
            return self.abort(addr, AbortCode::TooLong);
        }
        if received > 0 && received >= BUF {
            return self.abort(addr, AbortCode::OutOfMemory);
        }
        let n = SEGMENT_DATA.min(BUF - received);
        self.buf[received..received + n].copy_from_slice(&seg.data[..n]);
        if let State::BlockDown {
            expected: ref mut e,
            received: ref mut r,
            ..
        } = self.state
        {
            *e += 1;
            *r += SEGMENT_DATA;
        }
        if ends_sub_block {
            self.ack_sub_block(seg.seqno, seg.last);
        }
    }

    fn ack_sub_block(&mut self, ackseq: u8, done: bool) {
        if let State::BlockDown {
            expected: ref mut e,
            done: ref mut d,
            ref mut seen,
            ..
        } = self.state
        {
            *e = 1;
            *d = done;
            *seen = false;
        }
        self.send(ServerFrame::BlockDownloadAck {
            ackseq,
            blksize: self.config.block_size,
        });
    }
}
