//! The SDO client: the master side of one server node's default SDO channel, with a queue of
//! pending requests served one at a time, in order.

use core::time::Duration;

use heapless::Deque;

use super::AbortedBy;
use super::codec::{
    BlockSegment, ClientFrame, InitiateData, MAX_BLOCK_SIZE, SEGMENT_DATA, Segment, ServerFrame,
    frame_bytes, is_block_abort,
};
use super::crc::crc16;
use crate::can::Frame;
use crate::canopen::{AbortCode, Address, NodeId, ids};
use crate::time::Instant;

/// Identifies a queued request in the event that reports its completion.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub struct RequestId(u32);

impl RequestId {
    /// The raw number (assigned in submission order, wrapping).
    pub const fn get(self) -> u32 {
        self.0
    }
}

/// How a download goes over the bus.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum DownloadMode {
    /// Expedited for 1..=4 bytes, segmented otherwise.
    Auto,
    /// Expedited (1..=4 bytes only).
    Expedited,
    /// Segmented, with size indication.
    Segmented,
    /// Block transfer, with size indication and CRC if both sides support it.
    Block,
}

/// How an upload goes over the bus.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum UploadMode {
    /// Initiate upload; the server chooses expedited or segmented.
    Normal,
    /// Block upload (the server may switch to a normal upload below the client's threshold).
    Block,
}

/// How an [`SdoClient`] behaves.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct SdoClientConfig {
    /// The default silence, per exchange, after which a request is aborted with 0504 0000h and
    /// reported as [`SdoError::Timeout`].
    pub timeout: Duration,
    /// Segments per sub-block the client accepts in block uploads (1..=127; clamped).
    pub block_size: u8,
    /// Whether the client generates and checks block-transfer CRCs (`cc`).
    pub crc: bool,
    /// Block upload protocol switch threshold: 0 forbids the server to answer with a normal
    /// upload; otherwise values up to this many bytes may come that way.
    pub pst: u8,
    /// In a block upload, silence this long after a segment of an unfinished sub-block makes
    /// the client acknowledge what it has (the server then resends the rest). This recovers a
    /// lost last segment of a sub-block.
    pub sub_block_timeout: Duration,
}

impl Default for SdoClientConfig {
    fn default() -> Self {
        SdoClientConfig {
            timeout: Duration::from_millis(500),
            block_size: MAX_BLOCK_SIZE,
            crc: true,
            pst: 0,
            sub_block_timeout: Duration::from_millis(100),
        }
    }
}

/// Why a request could not be queued.
#[derive(Debug, Clone, Copy, PartialEq, Eq, thiserror::Error)]
pub enum RequestError {
    /// All `capacity` request slots are taken.
    #[error("the SDO request queue is full ({capacity} requests)")]
    QueueFull {
        /// The queue's capacity `Q`.
        capacity: usize,
    },
    /// The download data does not fit the free part of the client's data buffer.
    #[error("{len} bytes of download data do not fit the {free} free bytes of the buffer")]
    NoSpace {
        /// The data's length.
        len: usize,
        /// Free bytes in the buffer.
        free: usize,
    },
    /// An expedited download carries 1..=4 bytes.
    #[error("an expedited download carries 1 to 4 bytes, not {len}")]
    NotExpedited {
        /// The data's length.
        len: usize,
    },
}

/// Why a request failed.
#[derive(Debug, Clone, Copy, PartialEq, Eq, thiserror::Error)]
pub enum SdoError {
    /// An abort frame ended the transfer. A protocol error the client detects (wrong toggle,
    /// wrong index in an answer, a value too large for its buffer) is reported as an abort
    /// `by: Client` with the code the client sent.
    #[error("SDO transfer aborted by the {by:?}: {code}")]
    Aborted {
        /// The abort code.
        code: AbortCode,
        /// Who sent the abort frame.
        by: AbortedBy,
    },
    /// The server did not answer in time; the client sent abort 0504 0000h.
    #[error("SDO server did not answer within {timeout_ms} ms")]
    Timeout {
        /// The timeout that passed, in milliseconds.
        timeout_ms: u64,
    },
}

/// What a successful request produced.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Completion<'a> {
    /// The uploaded value, borrowed from the client until the next call that changes it.
    Uploaded(&'a [u8]),
    /// The download was confirmed by the server.
    Downloaded,
}

/// The completion of one request.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct SdoEvent<'a> {
    /// The request, as returned when it was queued.
    pub id: RequestId,
    /// The object it addressed.
    pub addr: Address,
    /// The value or the error.
    pub outcome: Result<Completion<'a>, SdoError>,
}

#[cfg(feature = "std")]
impl SdoEvent<'_> {
    /// The outcome with the uploaded bytes copied out (empty for a download): for callers that
    /// keep the result past the next call to the client.
    pub fn to_vec(&self) -> Result<std::vec::Vec<u8>, SdoError> {
        self.outcome.map(|c| match c {
            Completion::Uploaded(d) => d.to_vec(),
            Completion::Downloaded => std::vec::Vec::new(),
        })
    }
}

#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Kind {
    Upload(UploadMode),
    Download { mode: DownloadMode, len: usize },
}

#[derive(Debug, Clone, Copy, PartialEq, Eq)]
struct Request {
    id: RequestId,
    addr: Address,
    kind: Kind,
    timeout: Duration,
}

#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Phase {
    /// Waiting for the initiate download response of an expedited download.
    ExpeditedDown,
    /// Waiting for the initiate download response of a segmented download.
    SegDownInit,
    /// Waiting for the response to the segment ending at `next` with toggle `toggle`.
    SegDown {
        toggle: bool,
        next: usize,
        last: bool,
    },
    /// Waiting for the initiate upload response.
    UpInit,
    /// Waiting for an upload segment with toggle `toggle`.
    SegUp { toggle: bool, size: Option<u32> },
    /// Waiting for the initiate block download response.
    BlockDownInit,
    /// Sending (then awaiting the ack of) the sub-block starting at global segment `first`.
    BlockDown {
        first: usize,
        sent: u8,
        blksize: u8,
        server_crc: bool,
        sending: bool,
    },
    /// Waiting for the end block download response.
    BlockDownEnd,
    /// Waiting for the initiate block upload response.
    BlockUpInit,
    /// Receiving sub-blocks; `received` counts 7 bytes per in-sequence segment.
    BlockUp {
        expected: u8,
        size: Option<u32>,
        crc: bool,
        received: usize,
        done: bool,
        /// A segment arrived since the last acknowledge (see the sub-block timer).
        seen: bool,
    },
}

#[derive(Debug, Clone, Copy, PartialEq, Eq)]
struct Done {
    id: RequestId,
    addr: Address,
    outcome: Result<bool, SdoError>,
}

/// The master side of SDO for one server node.
///
/// Requests are queued (at most `Q`, the one on the wire included) and run one at a time in
/// submission order. Download data is copied into the client's `BUF`-byte buffer when queued
/// (all queued downloads share it); an upload's value is collected in a second `BUF`-byte
/// buffer and lent out by [`poll_event`](Self::poll_event). The next request starts only after
/// the previous completion was taken, so no result is overwritten unread.
///
/// ```
/// use drivers::canopen::sdo::{SdoClient, SdoClientConfig};
/// use drivers::canopen::{Address, NodeId};
/// use drivers::time::Instant;
/// let mut client: SdoClient<4, 64> = SdoClient::new(NodeId::new(1).unwrap(), SdoClientConfig::default());
/// client.upload(Address::new(0x1000, 0)).unwrap();
/// let f = client.poll_transmit(Instant::ZERO).unwrap();
/// assert_eq!(f.cob_id(), Some(0x601));
/// assert_eq!(f.data(), &[0x40, 0x00, 0x10, 0x00, 0, 0, 0, 0]);
/// ```
#[derive(Debug)]
pub struct SdoClient<const Q: usize, const BUF: usize> {
    node: NodeId,
    config: SdoClientConfig,
    queue: Deque<Request, Q>,
    phase: Option<Phase>,
    deadline: Option<Instant>,
    last_rx: Instant,
    data: [u8; BUF],
    data_used: usize,
    rx: [u8; BUF],
    rx_len: usize,
    tx: Deque<Frame, 2>,
    done: Option<Done>,
    next_id: u32,
    ignored: u32,
}

impl<const Q: usize, const BUF: usize> SdoClient<Q, BUF> {
    /// A client for the server at `node`.
    pub fn new(node: NodeId, mut config: SdoClientConfig) -> Self {
        config.block_size = config.block_size.clamp(1, MAX_BLOCK_SIZE);
        SdoClient {
            node,
            config,
            queue: Deque::new(),
            phase: None,
            deadline: None,
            last_rx: Instant::ZERO,
            data: [0; BUF],
            data_used: 0,
            rx: [0; BUF],
            rx_len: 0,
            tx: Deque::new(),
            done: None,
            next_id: 0,
            ignored: 0,
        }
    }

    /// The node of the server this client talks to.
    pub fn server_node(&self) -> NodeId {
        self.node
    }

    /// Whether `frame` comes from this client's server (COB-ID 580h + node, standard id), so a
    /// master can hand each received frame to the right client.
    pub fn accepts(&self, frame: &Frame) -> bool {
        frame.cob_id() == Some(ids::SDO_TX + self.node.get() as u16)
    }

    /// Requests queued or running.
    pub fn pending(&self) -> usize {
        self.queue.len()
    }

    /// Whether nothing is queued, running or waiting to be reported.
    pub fn is_idle(&self) -> bool {
        self.queue.is_empty() && self.done.is_none() && self.tx.is_empty()
    }

    /// Frames from the server that were ignored: not 8 bytes long, or arriving while no
    /// transfer was running.
    pub fn ignored_frames(&self) -> u32 {
        self.ignored
    }

    /// Queues a (normal) upload of `addr`.
    pub fn upload(&mut self, addr: Address) -> Result<RequestId, RequestError> {
        self.upload_with(addr, UploadMode::Normal, None)
    }

    /// Queues a block upload of `addr`.
    pub fn upload_block(&mut self, addr: Address) -> Result<RequestId, RequestError> {
        self.upload_with(addr, UploadMode::Block, None)
    }

    /// Queues an upload with an explicit mode and, optionally, its own timeout.
    pub fn upload_with(
        &mut self,
        addr: Address,
        mode: UploadMode,
        timeout: Option<Duration>,
    ) -> Result<RequestId, RequestError> {
        self.push(addr, Kind::Upload(mode), timeout)
    }

    /// Queues a download of `data` to `addr`. The data is copied into the client.
    pub fn download(
        &mut self,
        addr: Address,
        data: &[u8],
        mode: DownloadMode,
    ) -> Result<RequestId, RequestError> {
        self.download_with(addr, data, mode, None)
    }

    /// Queues a download with, optionally, its own timeout.
    pub fn download_with(
        &mut self,
        addr: Address,
        data: &[u8],
        mode: DownloadMode,
        timeout: Option<Duration>,
    ) -> Result<RequestId, RequestError> {
        let len = data.len();
        let mode = match mode {
            DownloadMode::Auto if (1..=4).contains(&len) => DownloadMode::Expedited,
            DownloadMode::Auto => DownloadMode::Segmented,
            DownloadMode::Expedited if !(1..=4).contains(&len) => {
                return Err(RequestError::NotExpedited { len });
            }
            m => m,
        };
        if self.queue.is_full() {
            return Err(RequestError::QueueFull { capacity: Q });
        }
        let free = BUF - self.data_used;
        if len > free {
            return Err(RequestError::NoSpace { len, free });
        }
        self.data[self.data_used..self.data_used + len].copy_from_slice(data);
        self.data_used += len;
        self.push(addr, Kind::Download { mode, len }, timeout)
    }

    fn push(
        &mut self,
        addr: Address,
        kind: Kind,
        timeout: Option<Duration>,
    ) -> Result<RequestId, RequestError> {
        let id = RequestId(self.next_id);
        let req = Request {
            id,
            addr,
            kind,
            timeout: timeout.unwrap_or(self.config.timeout),
        };
        self.queue
            .push_back(req)
            .map_err(|_| RequestError::QueueFull { capacity: Q })?;
        self.next_id = self.next_id.wrapping_add(1);
        Ok(id)
    }

    /// The next frame to send: a reply, the start of the next queued request, or the next
    /// segment of a block download's sub-block.
    pub fn poll_transmit(&mut self, now: Instant) -> Option<Frame> {
        if let Some(f) = self.tx.pop_front() {
            return Some(f);
        }
        let req = *self.queue.front()?;
        match self.phase {
            None if self.done.is_none() => {
                let f = self.start(req);
                self.deadline = Some(now + req.timeout);
                Some(self.frame(f))
            }
            Some(Phase::BlockDown {
                first,
                sent,
                blksize,
                server_crc,
                sending: true,
            }) => {
                let len = self.active_len();
                let total = Self::total_segments(len);
                let k = first + sent as usize;
                let start = (k * SEGMENT_DATA).min(len);
                let end = (start + SEGMENT_DATA).min(len);
                let last = k + 1 >= total;
                let sent = sent + 1;
                let seg = BlockSegment::new(sent, last, &self.data[start..end]);
                self.phase = Some(Phase::BlockDown {
                    first,
                    sent,
                    blksize,
                    server_crc,
                    sending: !(last || sent >= blksize),
                });
                self.deadline = Some(now + req.timeout);
                Some(Frame::std8(self.cob(), seg.to_bytes()))
            }
            _ => None,
        }
    }

    /// The completion of the last request, if not yet taken. Taking it lets the next queued
    /// request start.
    pub fn poll_event(&mut self) -> Option<SdoEvent<'_>> {
        let d = self.done.take()?;
        let outcome = match d.outcome {
            Ok(true) => Ok(Completion::Uploaded(&self.rx[..self.rx_len.min(BUF)])),
            Ok(false) => Ok(Completion::Downloaded),
            Err(e) => Err(e),
        };
        Some(SdoEvent {
            id: d.id,
            addr: d.addr,
            outcome,
        })
    }

    /// When [`handle_timeout`](Self::handle_timeout) must be called next, if the client waits
    /// for its server.
    pub fn poll_timeout(&self) -> Option<Instant> {
        match self.phase {
            None | Some(Phase::BlockDown { sending: true, .. }) => None,
            Some(Phase::BlockUp {
                done: false,
                seen: true,
                ..
            }) => {
                let sub = self.last_rx + self.config.sub_block_timeout;
                self.deadline.map(|d| d.min(sub))
            }
            Some(_) => self.deadline,
        }
    }

    /// Acts on the passage of time: a request whose server stayed silent past its timeout is
    /// aborted (0504 0000h sent) and reported as [`SdoError::Timeout`].
    pub fn handle_timeout(&mut self, now: Instant) {
        let Some(deadline) = self.poll_timeout() else {
            return;
        };
        if now < deadline {
            return;
        }
        if let Some(Phase::BlockUp {
            done: false,
            seen: true,
            expected,
            size,
            crc,
            received,
        }) = self.phase
            && self.deadline.is_some_and(|d| now < d)
        {
            // Only after a segment since the last ack: with nothing received, the client could
            // not tell a lost ack from a lost sub-block, and a guess would corrupt the value.
            self.phase = Some(Phase::BlockUp {
                expected: 1,
                size,
                crc,
                received,
                done: false,
                seen: false,
            });
            self.send(ClientFrame::BlockUploadAck {
                ackseq: expected - 1,
                blksize: self.config.block_size,
            });
            return;
        }
        let Some(req) = self.queue.front().copied() else {
            return;
        };
        self.send(ClientFrame::Abort {
            addr: req.addr,
            code: AbortCode::Timeout,
        });
        let timeout_ms = req.timeout.as_millis().min(u64::MAX as u128) as u64;
        self.finish(Err(SdoError::Timeout { timeout_ms }));
    }

    /// Feeds one received frame. Frames for other COB-IDs are ignored.
    pub fn handle_frame(&mut self, frame: &Frame, now: Instant) {
        if !self.accepts(frame) {
            return;
        }
        let (Some(phase), Some(req)) = (self.phase, self.queue.front().copied()) else {
            self.ignored = self.ignored.saturating_add(1);
            return;
        };
        let Ok(b) = frame_bytes(frame) else {
            self.ignored = self.ignored.saturating_add(1);
            return;
        };
        self.deadline = Some(now + req.timeout);
        self.last_rx = now;
        if let Phase::BlockUp { done: false, .. } = phase
            && !is_block_abort(&b)
        {
            return self.block_up_segment(&b, req);
        }
        let f = match ServerFrame::decode(&b) {
            Ok(f) => f,
            Err(e) => return self.protocol_error(req, e.abort_code()),
        };
        if let ServerFrame::Abort { code, .. } = f {
            return self.finish(Err(SdoError::Aborted {
                code,
                by: AbortedBy::Server,
            }));
        }
        // Answers that name an object must name ours (the server may still be answering a
        // request we gave up on).
        let echoed = match f {
            ServerFrame::InitiateUpload { addr, .. }
            | ServerFrame::InitiateDownload { addr }
            | ServerFrame::BlockDownloadInitiate { addr, .. }
            | ServerFrame::BlockUploadInitiate { addr, .. } => Some(addr),
            _ => None,
        };
        if echoed.is_some_and(|a| a != req.addr) {
            return self.protocol_error(req, AbortCode::ParamIncompatible);
        }
        self.dispatch(f, phase, req);
    }

    fn dispatch(&mut self, f: ServerFrame, phase: Phase, req: Request) {
        match (f, phase) {
            (ServerFrame::InitiateDownload { .. }, Phase::ExpeditedDown) => self.finish(Ok(false)),
            (ServerFrame::InitiateDownload { .. }, Phase::SegDownInit) => {
                self.send_download_segment(false, 0)
            }
            (ServerFrame::DownloadSegment { toggle: t }, Phase::SegDown { toggle, next, last }) => {
                if t != toggle {
                    self.protocol_error(req, AbortCode::ToggleBit)
                } else if last {
                    self.finish(Ok(false))
                } else {
                    self.send_download_segment(!toggle, next)
                }
            }
            (ServerFrame::InitiateUpload { data, .. }, Phase::UpInit | Phase::BlockUpInit) => {
                match data {
                    InitiateData::Expedited { data, len } => {
                        let l = len.map_or(4, usize::from).min(4);
                        if l > BUF {
                            return self.protocol_error(req, AbortCode::OutOfMemory);
                        }
                        self.rx[..l].copy_from_slice(&data[..l]);
                        self.rx_len = l;
                        self.finish(Ok(true))
                    }
                    InitiateData::Segmented { size } => {
                        if size.is_some_and(|s| s as usize > BUF) {
                            return self.protocol_error(req, AbortCode::OutOfMemory);
                        }
                        self.rx_len = 0;
                        self.phase = Some(Phase::SegUp {
                            toggle: false,
                            size,
                        });
                        self.send(ClientFrame::UploadSegment { toggle: false });
                    }
                }
            }
            (ServerFrame::UploadSegment(seg), Phase::SegUp { toggle, size }) => {
                if seg.toggle != toggle {
                    return self.protocol_error(req, AbortCode::ToggleBit);
                }
                let p = seg.payload();
                let new_len = self.rx_len + p.len();
                if size.is_some_and(|s| new_len > s as usize) {
                    return self.protocol_error(req, AbortCode::TooLong);
                }
                if new_len > BUF {
                    return self.protocol_error(req, AbortCode::OutOfMemory);
                }
                self.rx[self.rx_len..new_len].copy_from_slice(p);
                self.rx_len = new_len;
                if seg.last {
                    if size.is_some_and(|s| new_len < s as usize) {
                        return self.protocol_error(req, AbortCode::TooShort);
                    }
                    self.finish(Ok(true))
                } else {
                    self.phase = Some(Phase::SegUp {
                        toggle: !toggle,
                        size,
                    });
                    self.send(ClientFrame::UploadSegment { toggle: !toggle });
                }
            }
            (ServerFrame::BlockDownloadInitiate { crc, blksize, .. }, Phase::BlockDownInit) => {
                self.phase = Some(Phase::BlockDown {
                    first: 0,
                    sent: 0,
                    blksize,
                    server_crc: crc,
                    sending: true,
                });
            }
            (
                ServerFrame::BlockDownloadAck { ackseq, blksize },
                Phase::BlockDown {
                    first,
                    sent,
                    server_crc,
                    ..
                },
            ) => {
                if ackseq > sent {
                    return self.protocol_error(req, AbortCode::InvalidSequence);
                }
                let len = self.active_len();
                let total = Self::total_segments(len);
                let acked = first + ackseq as usize;
                if acked >= total {
                    let unused = (total * SEGMENT_DATA - len) as u8;
                    let crc = if server_crc && self.config.crc {
                        crc16(&self.data[..len])
                    } else {
                        0
                    };
                    self.phase = Some(Phase::BlockDownEnd);
                    self.send(ClientFrame::BlockDownloadEnd { unused, crc });
                } else {
                    // A partial ackseq: the next sub-block restarts at the first segment the
                    // server did not confirm (CiA 301 block download).
                    self.phase = Some(Phase::BlockDown {
                        first: acked,
                        sent: 0,
                        blksize,
                        server_crc,
                        sending: true,
                    });
                }
            }
            (ServerFrame::BlockDownloadEnd, Phase::BlockDownEnd) => self.finish(Ok(false)),
            (ServerFrame::BlockUploadInitiate { crc, size, .. }, Phase::BlockUpInit) => {
                if size.is_some_and(|s| s as usize > BUF) {
                    return self.protocol_error(req, AbortCode::OutOfMemory);
                }
                self.rx_len = 0;
                self.phase = Some(Phase::BlockUp {
                    expected: 1,
                    size,
                    crc: crc && self.config.crc,
                    received: 0,
                    done: false,
                    seen: false,
                });
                self.send(ClientFrame::BlockUploadStart);
            }
            (
                ServerFrame::BlockUploadEnd { unused, crc },
                Phase::BlockUp {
                    size,
                    crc: crc_on,
                    received,
                    done: true,
                    ..
                },
            ) => {
                let Some(real) = received.checked_sub(unused as usize) else {
                    return self.protocol_error(req, AbortCode::TooShort);
                };
                if real > BUF {
                    return self.protocol_error(req, AbortCode::OutOfMemory);
                }
                if let Some(s) = size {
                    if real < s as usize {
                        return self.protocol_error(req, AbortCode::TooShort);
                    }
                    if real > s as usize {
                        return self.protocol_error(req, AbortCode::TooLong);
                    }
                }
                if crc_on && crc16(&self.rx[..real]) != crc {
                    return self.protocol_error(req, AbortCode::CrcError);
                }
                self.rx_len = real;
                self.send(ClientFrame::BlockUploadEnd);
                self.finish(Ok(true))
            }
            _ => self.protocol_error(req, AbortCode::InvalidCommand),
        }
    }

    fn block_up_segment(&mut self, b: &[u8; 8], req: Request) {
        let Some(Phase::BlockUp {
            expected,
            size,
            crc,
            received,
            ..
        }) = self.phase
        else {
            return;
        };
        let seg = match BlockSegment::decode(b) {
            Ok(s) => s,
            Err(e) => return self.protocol_error(req, e.abort_code()),
        };
        let blksize = self.config.block_size;
        let ends = seg.last || seg.seqno >= blksize;
        if seg.seqno != expected {
            // Dropped; the ack at the end of the sub-block makes the server resend from here.
            self.phase = Some(Phase::BlockUp {
                expected: if ends { 1 } else { expected },
                size,
                crc,
                received,
                done: false,
                seen: !ends,
            });
            if ends {
                self.send(ClientFrame::BlockUploadAck {
                    ackseq: expected - 1,
                    blksize,
                });
            }
            return;
        }
        // The first segment is always due (an empty value still takes one).
        if received > 0 && size.is_some_and(|s| received >= s as usize) {
            return self.protocol_error(req, AbortCode::TooLong);
        }
        if received > 0 && received >= BUF {
            return self.protocol_error(req, AbortCode::OutOfMemory);
        }
        let n = SEGMENT_DATA.min(BUF - received);
        self.rx[received..received + n].copy_from_slice(&seg.data[..n]);
        let received = received + SEGMENT_DATA;
        self.phase = Some(Phase::BlockUp {
            expected: if ends { 1 } else { expected + 1 },
            size,
            crc,
            received,
            done: seg.last,
            seen: !ends,
        });
        if ends {
            self.send(ClientFrame::BlockUploadAck {
                ackseq: seg.seqno,
                blksize,
            });
        }
    }

    fn start(&mut self, req: Request) -> ClientFrame {
        let addr = req.addr;
        match req.kind {
            Kind::Upload(UploadMode::Normal) => {
                self.phase = Some(Phase::UpInit);
                ClientFrame::InitiateUpload { addr }
            }
            Kind::Upload(UploadMode::Block) => {
                self.phase = Some(Phase::BlockUpInit);
                ClientFrame::BlockUploadInitiate {
                    addr,
                    crc: self.config.crc,
                    blksize: self.config.block_size,
                    pst: self.config.pst,
                }
            }
            Kind::Download { mode, len } => match mode {
                DownloadMode::Expedited | DownloadMode::Auto if (1..=4).contains(&len) => {
                    self.phase = Some(Phase::ExpeditedDown);
                    let data = InitiateData::expedited(&self.data[..len]).unwrap_or(
                        InitiateData::Segmented {
                            size: Some(len as u32),
                        },
                    );
                    ClientFrame::InitiateDownload { addr, data }
                }
                DownloadMode::Block => {
                    self.phase = Some(Phase::BlockDownInit);
                    ClientFrame::BlockDownloadInitiate {
                        addr,
                        crc: self.config.crc,
                        size: u32::try_from(len).ok(),
                    }
                }
                _ => {
                    self.phase = Some(Phase::SegDownInit);
                    ClientFrame::InitiateDownload {
                        addr,
                        data: InitiateData::Segmented {
                            size: u32::try_from(len).ok(),
                        },
                    }
                }
            },
        }
    }

    fn send_download_segment(&mut self, toggle: bool, from: usize) {
        let len = self.active_len();
        let from = from.min(len);
        let end = (from + SEGMENT_DATA).min(len);
        let last = end >= len;
        let seg = Segment::new(toggle, &self.data[from..end], last);
        self.phase = Some(Phase::SegDown {
            toggle,
            next: end,
            last,
        });
        self.send(ClientFrame::DownloadSegment(seg));
    }

    /// Segments a block transfer of `len` bytes needs (an empty value still takes one).
    fn total_segments(len: usize) -> usize {
        len.div_ceil(SEGMENT_DATA).max(1)
    }

    /// The length of the running request's download data (at the front of the buffer).
    fn active_len(&self) -> usize {
        match self.queue.front() {
            Some(Request {
                kind: Kind::Download { len, .. },
                ..
            }) => (*len).min(self.data_used),
            _ => 0,
        }
    }

    fn cob(&self) -> u16 {
        ids::SDO_RX + self.node.get() as u16
    }

    fn frame(&self, f: ClientFrame) -> Frame {
        Frame::std8(self.cob(), f.to_bytes())
    }

    fn send(&mut self, f: ClientFrame) {
        let frame = self.frame(f);
        if self.tx.is_full() {
            self.tx.pop_front();
        }
        let _ = self.tx.push_back(frame);
    }

    fn protocol_error(&mut self, req: Request, code: AbortCode) {
        self.send(ClientFrame::Abort {
            addr: req.addr,
            code,
        });
        self.finish(Err(SdoError::Aborted {
            code,
            by: AbortedBy::Client,
        }));
    }

    /// Ends the running request: its data leaves the buffer, its outcome waits for
    /// [`poll_event`](Self::poll_event).
    fn finish(&mut self, outcome: Result<bool, SdoError>) {
        let Some(req) = self.queue.pop_front() else {
            return;
        };
        if let Kind::Download { len, .. } = req.kind {
            let len = len.min(self.data_used);
            self.data.copy_within(len..self.data_used, 0);
            self.data_used -= len;
        }
        if outcome.is_err() {
            self.rx_len = 0;
        }
        self.phase = None;
        self.deadline = None;
        self.done = Some(Done {
            id: req.id,
            addr: req.addr,
            outcome,
        });
    }
}
