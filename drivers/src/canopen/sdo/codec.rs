//! The SDO frame layouts of CiA 301 §7.2.4.3, written once for both directions.
//!
//! Every SDO frame is 8 bytes. Byte 0 holds the command specifier (bits 7..5) and its flags;
//! initiate and abort frames carry the multiplexer (index LE in bytes 1..=2, sub-index in byte
//! 3). Segments of a block transfer carry no command specifier at all (byte 0 is `c | seqno`),
//! so which decoder applies depends on the transfer's state: [`ClientFrame::decode`] and
//! [`ServerFrame::decode`] read command frames, [`BlockSegment::decode`] reads sub-block
//! segments.

use crate::can::Frame;
use crate::canopen::{AbortCode, Address};

/// Data bytes per segment (segmented and block transfer).
pub const SEGMENT_DATA: usize = 7;
/// The largest block size (segments per sub-block) and sequence number.
pub const MAX_BLOCK_SIZE: u8 = 127;

/// Why 8 bytes are not a valid SDO frame.
#[derive(Debug, Clone, Copy, PartialEq, Eq, thiserror::Error)]
pub enum DecodeError {
    /// The frame does not carry exactly 8 data bytes (the DLC, or 0 for a remote frame).
    #[error("an SDO frame carries 8 data bytes, this one {0}")]
    Length(usize),
    /// The command specifier (byte 0) is not defined in this direction.
    #[error("SDO command byte {0:#04x} is not valid in this direction")]
    UnknownCommand(u8),
    /// A block size outside 1..=127.
    #[error("SDO block size {0} is outside 1..=127")]
    BlockSize(u8),
    /// A segment sequence number outside 1..=127.
    #[error("SDO block sequence number {0} is outside 1..=127")]
    SeqNo(u8),
    /// An acknowledged sequence number above 127.
    #[error("SDO block ackseq {0} is above 127")]
    AckSeq(u8),
}

impl DecodeError {
    /// The abort code that answers this error on the bus.
    pub const fn abort_code(self) -> AbortCode {
        match self {
            DecodeError::Length(_) => AbortCode::General,
            DecodeError::UnknownCommand(_) => AbortCode::InvalidCommand,
            DecodeError::BlockSize(_) => AbortCode::InvalidBlockSize,
            DecodeError::SeqNo(_) | DecodeError::AckSeq(_) => AbortCode::InvalidSequence,
        }
    }
}

/// The 8 data bytes of an SDO frame, or [`DecodeError::Length`] if it has another length (a
/// remote frame counts as 0 bytes).
pub fn frame_bytes(frame: &Frame) -> Result<[u8; 8], DecodeError> {
    if frame.is_remote() || frame.dlc() != 8 {
        return Err(DecodeError::Length(frame.data().len()));
    }
    Ok(frame.data8())
}

/// How an initiate frame (download request, upload response) carries its data.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum InitiateData {
    /// `e = 1`: the value is in bytes 4..=7. `len` is `Some(1..=4)` with size indication
    /// (`s = 1`, `n = 4 - len`), `None` when the size is not indicated.
    Expedited {
        /// Bytes 4..=7 as sent.
        data: [u8; 4],
        /// The number of valid bytes, if indicated.
        len: Option<u8>,
    },
    /// `e = 0`: segments follow. `size` is the total in bytes if indicated (`s = 1`).
    Segmented {
        /// The announced size.
        size: Option<u32>,
    },
}

impl InitiateData {
    /// Expedited data with size indication, or `None` unless `value` is 1..=4 bytes.
    pub fn expedited(value: &[u8]) -> Option<InitiateData> {
        if value.is_empty() || value.len() > 4 {
            return None;
        }
        let mut data = [0u8; 4];
        data[..value.len()].copy_from_slice(value);
        Some(InitiateData::Expedited {
            data,
            len: Some(value.len() as u8),
        })
    }

    /// Flag bits `n e s` (bits 3..0 of byte 0) and bytes 4..=7.
    fn encode(self) -> (u8, [u8; 4]) {
        match self {
            InitiateData::Expedited { data, len: Some(l) } => {
                let l = l.clamp(1, 4);
                (((4 - l) << 2) | 0b11, data)
            }
            InitiateData::Expedited { data, len: None } => (0b10, data),
            InitiateData::Segmented { size: Some(s) } => (0b01, s.to_le_bytes()),
            InitiateData::Segmented { size: None } => (0b00, [0; 4]),
        }
    }

    fn decode(b: &[u8; 8]) -> InitiateData {
        let d = [b[4], b[5], b[6], b[7]];
        let expedited = b[0] & 0b10 != 0;
        let sized = b[0] & 0b01 != 0;
        match (expedited, sized) {
            (true, true) => InitiateData::Expedited {
                data: d,
                len: Some(4 - ((b[0] >> 2) & 0b11)),
            },
            (true, false) => InitiateData::Expedited { data: d, len: None },
            (false, true) => InitiateData::Segmented {
                size: Some(u32::from_le_bytes(d)),
            },
            (false, false) => InitiateData::Segmented { size: None },
        }
    }
}

/// A segment of a segmented transfer: `t nnn c` in byte 0, up to 7 data bytes. The same layout
/// serves download segments (client) and upload segment responses (server).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Segment {
    /// The toggle bit `t`, 0 in the first segment, alternating.
    pub toggle: bool,
    /// The data bytes; the first `len` are valid.
    pub data: [u8; 7],
    /// `7 - n`: how many bytes of `data` are valid.
    pub len: u8,
    /// `c`: no more segments follow.
    pub last: bool,
}

impl Segment {
    /// A segment carrying `chunk` (at most 7 bytes; longer input is cut to 7).
    pub fn new(toggle: bool, chunk: &[u8], last: bool) -> Segment {
        let n = chunk.len().min(SEGMENT_DATA);
        let mut data = [0u8; 7];
        data[..n].copy_from_slice(&chunk[..n]);
        Segment {
            toggle,
            data,
            len: n as u8,
            last,
        }
    }
    /// The valid data bytes.
    pub fn payload(&self) -> &[u8] {
        &self.data[..(self.len as usize).min(SEGMENT_DATA)]
    }
    fn encode(&self, ccs: u8) -> [u8; 8] {
        let n = 7 - self.len.min(7);
        let mut b = [0u8; 8];
        b[0] = (ccs << 5) | ((self.toggle as u8) << 4) | (n << 1) | self.last as u8;
        b[1..].copy_from_slice(&self.data);
        b
    }
    fn decode(b: &[u8; 8]) -> Segment {
        let mut data = [0u8; 7];
        data.copy_from_slice(&b[1..]);
        Segment {
            toggle: b[0] & 0x10 != 0,
            data,
            len: 7 - ((b[0] >> 1) & 0b111),
            last: b[0] & 1 != 0,
        }
    }
}

/// A segment of a block transfer sub-block: byte 0 is `c | seqno`, bytes 1..=7 data (the last
/// segment's unused bytes are announced by `n` in the end frame).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct BlockSegment {
    /// The sequence number within the sub-block, 1..=127.
    pub seqno: u8,
    /// `c`: the last segment of the whole transfer.
    pub last: bool,
    /// Seven data bytes.
    pub data: [u8; 7],
}

impl BlockSegment {
    /// A segment carrying `chunk` (at most 7 bytes, zero padded; longer input is cut to 7).
    pub fn new(seqno: u8, last: bool, chunk: &[u8]) -> BlockSegment {
        let n = chunk.len().min(SEGMENT_DATA);
        let mut data = [0u8; 7];
        data[..n].copy_from_slice(&chunk[..n]);
        BlockSegment { seqno, last, data }
    }
    /// Decodes a sub-block segment. Byte 0 `0x80` (c set, seqno 0) is an abort, not a segment,
    /// and decodes as [`DecodeError::SeqNo`]; check with [`is_block_abort`] first.
    pub fn decode(b: &[u8]) -> Result<BlockSegment, DecodeError> {
        let b: &[u8; 8] = b.try_into().map_err(|_| DecodeError::Length(b.len()))?;
        let seqno = b[0] & 0x7F;
        if seqno == 0 {
            return Err(DecodeError::SeqNo(seqno));
        }
        let mut data = [0u8; 7];
        data.copy_from_slice(&b[1..]);
        Ok(BlockSegment {
            seqno,
            last: b[0] & 0x80 != 0,
            data,
        })
    }
    /// The 8 bytes on the wire.
    pub fn to_bytes(&self) -> [u8; 8] {
        let mut b = [0u8; 8];
        b[0] = ((self.last as u8) << 7) | (self.seqno & 0x7F);
        b[1..].copy_from_slice(&self.data);
        b
    }
}

/// Whether 8 bytes are an abort frame while sub-block segments are expected. There `0x81` to
/// `0x9F` are last segments (`c` set, seqno 1..=31), so only `0x80` (seqno 0, never a segment)
/// can be an abort; outside sub-blocks any command byte `100x xxxx` is one.
pub fn is_block_abort(b: &[u8]) -> bool {
    b.len() == 8 && b.first() == Some(&0x80)
}

fn addr_of(b: &[u8; 8]) -> Address {
    Address::from_sdo_bytes([b[1], b[2], b[3]])
}

fn with_addr(cmd: u8, addr: Address, tail: [u8; 4]) -> [u8; 8] {
    let a = addr.to_sdo_bytes();
    [cmd, a[0], a[1], a[2], tail[0], tail[1], tail[2], tail[3]]
}

fn block_size(b: u8) -> Result<u8, DecodeError> {
    if (1..=MAX_BLOCK_SIZE).contains(&b) {
        Ok(b)
    } else {
        Err(DecodeError::BlockSize(b))
    }
}

fn ack_seq(b: u8) -> Result<u8, DecodeError> {
    if b <= MAX_BLOCK_SIZE {
        Ok(b)
    } else {
        Err(DecodeError::AckSeq(b))
    }
}

/// A command frame from client to server (COB-ID 600h + node).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum ClientFrame {
    /// ccs 1: initiate download, expedited or segmented.
    InitiateDownload {
        /// The object written.
        addr: Address,
        /// The value (expedited) or the announced size (segmented).
        data: InitiateData,
    },
    /// ccs 0: download segment.
    DownloadSegment(Segment),
    /// ccs 2: initiate upload.
    InitiateUpload {
        /// The object read.
        addr: Address,
    },
    /// ccs 3: upload segment request.
    UploadSegment {
        /// The toggle bit the server must echo.
        toggle: bool,
    },
    /// ccs 4: abort transfer.
    Abort {
        /// The object of the aborted transfer.
        addr: Address,
        /// Why.
        code: AbortCode,
    },
    /// ccs 6, cs 0: initiate block download.
    BlockDownloadInitiate {
        /// The object written.
        addr: Address,
        /// `cc`: the client generates the CRC.
        crc: bool,
        /// The announced size (`s = 1`).
        size: Option<u32>,
    },
    /// ccs 6, cs 1: end block download.
    BlockDownloadEnd {
        /// `n`: bytes of the last segment that carry no data (0..=7).
        unused: u8,
        /// The CRC of the whole value (0 without CRC support).
        crc: u16,
    },
    /// ccs 5, cs 0: initiate block upload.
    BlockUploadInitiate {
        /// The object read.
        addr: Address,
        /// `cc`: the client checks the CRC.
        crc: bool,
        /// Segments per sub-block the client accepts, 1..=127.
        blksize: u8,
        /// Protocol switch threshold: the server may answer a value of at most `pst` bytes
        /// with a normal upload; 0 forbids it.
        pst: u8,
    },
    /// ccs 5, cs 3: start the block upload.
    BlockUploadStart,
    /// ccs 5, cs 2: acknowledge a sub-block.
    BlockUploadAck {
        /// The last segment received in sequence (0: none).
        ackseq: u8,
        /// Segments per sub-block for the next one, 1..=127.
        blksize: u8,
    },
    /// ccs 5, cs 1: the client's end-of-block-upload response.
    BlockUploadEnd,
}

impl ClientFrame {
    /// Decodes a command frame the client sent. Sub-block segments are not command frames:
    /// decode those with [`BlockSegment::decode`].
    pub fn decode(b: &[u8]) -> Result<ClientFrame, DecodeError> {
        let b: &[u8; 8] = b.try_into().map_err(|_| DecodeError::Length(b.len()))?;
        let c = b[0];
        Ok(match c >> 5 {
            0 => ClientFrame::DownloadSegment(Segment::decode(b)),
            1 => ClientFrame::InitiateDownload {
                addr: addr_of(b),
                data: InitiateData::decode(b),
            },
            2 => ClientFrame::InitiateUpload { addr: addr_of(b) },
            3 => ClientFrame::UploadSegment {
                toggle: c & 0x10 != 0,
            },
            4 => ClientFrame::Abort {
                addr: addr_of(b),
                code: AbortCode::from_code(u32::from_le_bytes([b[4], b[5], b[6], b[7]])),
            },
            5 => match c & 0b11 {
                0 => ClientFrame::BlockUploadInitiate {
                    addr: addr_of(b),
                    crc: c & 0b100 != 0,
                    blksize: block_size(b[4])?,
                    pst: b[5],
                },
                1 => ClientFrame::BlockUploadEnd,
                2 => ClientFrame::BlockUploadAck {
                    ackseq: ack_seq(b[1])?,
                    blksize: block_size(b[2])?,
                },
                _ => ClientFrame::BlockUploadStart,
            },
            6 => match c & 0b1 {
                0 => ClientFrame::BlockDownloadInitiate {
                    addr: addr_of(b),
                    crc: c & 0b100 != 0,
                    size: (c & 0b10 != 0).then(|| u32::from_le_bytes([b[4], b[5], b[6], b[7]])),
                },
                _ => ClientFrame::BlockDownloadEnd {
                    unused: (c >> 2) & 0b111,
                    crc: u16::from_le_bytes([b[1], b[2]]),
                },
            },
            _ => return Err(DecodeError::UnknownCommand(c)),
        })
    }

    /// Decodes a frame from the bus, checking its length first.
    pub fn from_frame(frame: &Frame) -> Result<ClientFrame, DecodeError> {
        ClientFrame::decode(&frame_bytes(frame)?)
    }

    /// The 8 bytes on the wire; reserved bits and bytes are 0.
    pub fn to_bytes(&self) -> [u8; 8] {
        match *self {
            ClientFrame::InitiateDownload { addr, data } => {
                let (flags, tail) = data.encode();
                with_addr(0x20 | flags, addr, tail)
            }
            ClientFrame::DownloadSegment(s) => s.encode(0),
            ClientFrame::InitiateUpload { addr } => with_addr(0x40, addr, [0; 4]),
            ClientFrame::UploadSegment { toggle } => {
                [0x60 | ((toggle as u8) << 4), 0, 0, 0, 0, 0, 0, 0]
            }
            ClientFrame::Abort { addr, code } => with_addr(0x80, addr, code.to_le_bytes()),
            ClientFrame::BlockDownloadInitiate { addr, crc, size } => {
                let c = 0xC0 | ((crc as u8) << 2) | ((size.is_some() as u8) << 1);
                with_addr(c, addr, size.unwrap_or(0).to_le_bytes())
            }
            ClientFrame::BlockDownloadEnd { unused, crc } => {
                let c = crc.to_le_bytes();
                [0xC1 | ((unused & 0b111) << 2), c[0], c[1], 0, 0, 0, 0, 0]
            }
            ClientFrame::BlockUploadInitiate {
                addr,
                crc,
                blksize,
                pst,
            } => with_addr(0xA0 | ((crc as u8) << 2), addr, [blksize, pst, 0, 0]),
            ClientFrame::BlockUploadStart => [0xA3, 0, 0, 0, 0, 0, 0, 0],
            ClientFrame::BlockUploadAck { ackseq, blksize } => {
                [0xA2, ackseq, blksize, 0, 0, 0, 0, 0]
            }
            ClientFrame::BlockUploadEnd => [0xA1, 0, 0, 0, 0, 0, 0, 0],
        }
    }
}

/// A command frame from server to client (COB-ID 580h + node).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum ServerFrame {
    /// scs 2: initiate upload response, expedited or segmented.
    InitiateUpload {
        /// The object read (echoed).
        addr: Address,
        /// The value (expedited) or the announced size (segmented).
        data: InitiateData,
    },
    /// scs 0: upload segment response.
    UploadSegment(Segment),
    /// scs 3: initiate download response.
    InitiateDownload {
        /// The object written (echoed).
        addr: Address,
    },
    /// scs 1: download segment response.
    DownloadSegment {
        /// The toggle bit of the acknowledged segment.
        toggle: bool,
    },
    /// scs 4: abort transfer.
    Abort {
        /// The object of the aborted transfer.
        addr: Address,
        /// Why.
        code: AbortCode,
    },
    /// scs 5, ss 0: initiate block download response.
    BlockDownloadInitiate {
        /// The object written (echoed).
        addr: Address,
        /// `sc`: the server checks the CRC.
        crc: bool,
        /// Segments per sub-block the server accepts, 1..=127.
        blksize: u8,
    },
    /// scs 5, ss 2: block download sub-block acknowledge.
    BlockDownloadAck {
        /// The last segment received in sequence (0: none).
        ackseq: u8,
        /// Segments per sub-block for the next one, 1..=127.
        blksize: u8,
    },
    /// scs 5, ss 1: the server's end-of-block-download response.
    BlockDownloadEnd,
    /// scs 6, ss 0: initiate block upload response.
    BlockUploadInitiate {
        /// The object read (echoed).
        addr: Address,
        /// `sc`: the server generates the CRC.
        crc: bool,
        /// The size, if indicated.
        size: Option<u32>,
    },
    /// scs 6, ss 1: end block upload.
    BlockUploadEnd {
        /// `n`: bytes of the last segment that carry no data (0..=7).
        unused: u8,
        /// The CRC of the whole value (0 without CRC support).
        crc: u16,
    },
}

impl ServerFrame {
    /// Decodes a command frame the server sent. Sub-block segments of a block upload are not
    /// command frames: decode those with [`BlockSegment::decode`].
    pub fn decode(b: &[u8]) -> Result<ServerFrame, DecodeError> {
        let b: &[u8; 8] = b.try_into().map_err(|_| DecodeError::Length(b.len()))?;
        let c = b[0];
        Ok(match c >> 5 {
            0 => ServerFrame::UploadSegment(Segment::decode(b)),
            1 => ServerFrame::DownloadSegment {
                toggle: c & 0x10 != 0,
            },
            2 => ServerFrame::InitiateUpload {
                addr: addr_of(b),
                data: InitiateData::decode(b),
            },
            3 => ServerFrame::InitiateDownload { addr: addr_of(b) },
            4 => ServerFrame::Abort {
                addr: addr_of(b),
                code: AbortCode::from_code(u32::from_le_bytes([b[4], b[5], b[6], b[7]])),
            },
            5 => match c & 0b11 {
                0 => ServerFrame::BlockDownloadInitiate {
                    addr: addr_of(b),
                    crc: c & 0b100 != 0,
                    blksize: block_size(b[4])?,
                },
                1 => ServerFrame::BlockDownloadEnd,
                2 => ServerFrame::BlockDownloadAck {
                    ackseq: ack_seq(b[1])?,
                    blksize: block_size(b[2])?,
                },
                _ => return Err(DecodeError::UnknownCommand(c)),
            },
            6 => match c & 0b1 {
                0 => ServerFrame::BlockUploadInitiate {
                    addr: addr_of(b),
                    crc: c & 0b100 != 0,
                    size: (c & 0b10 != 0).then(|| u32::from_le_bytes([b[4], b[5], b[6], b[7]])),
                },
                _ => ServerFrame::BlockUploadEnd {
                    unused: (c >> 2) & 0b111,
                    crc: u16::from_le_bytes([b[1], b[2]]),
                },
            },
            _ => return Err(DecodeError::UnknownCommand(c)),
        })
    }

    /// Decodes a frame from the bus, checking its length first.
    pub fn from_frame(frame: &Frame) -> Result<ServerFrame, DecodeError> {
        ServerFrame::decode(&frame_bytes(frame)?)
    }

    /// The 8 bytes on the wire; reserved bits and bytes are 0.
    pub fn to_bytes(&self) -> [u8; 8] {
        match *self {
            ServerFrame::InitiateUpload { addr, data } => {
                let (flags, tail) = data.encode();
                with_addr(0x40 | flags, addr, tail)
            }
            ServerFrame::UploadSegment(s) => s.encode(0),
            ServerFrame::InitiateDownload { addr } => with_addr(0x60, addr, [0; 4]),
            ServerFrame::DownloadSegment { toggle } => {
                [0x20 | ((toggle as u8) << 4), 0, 0, 0, 0, 0, 0, 0]
            }
            ServerFrame::Abort { addr, code } => with_addr(0x80, addr, code.to_le_bytes()),
            ServerFrame::BlockDownloadInitiate { addr, crc, blksize } => {
                with_addr(0xA0 | ((crc as u8) << 2), addr, [blksize, 0, 0, 0])
            }
            ServerFrame::BlockDownloadAck { ackseq, blksize } => {
                [0xA2, ackseq, blksize, 0, 0, 0, 0, 0]
            }
            ServerFrame::BlockDownloadEnd => [0xA1, 0, 0, 0, 0, 0, 0, 0],
            ServerFrame::BlockUploadInitiate { addr, crc, size } => {
                let c = 0xC0 | ((crc as u8) << 2) | ((size.is_some() as u8) << 1);
                with_addr(c, addr, size.unwrap_or(0).to_le_bytes())
            }
            ServerFrame::BlockUploadEnd { unused, crc } => {
                let c = crc.to_le_bytes();
                [0xC1 | ((unused & 0b111) << 2), c[0], c[1], 0, 0, 0, 0, 0]
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const A: Address = Address::new(0x1000, 0);

    #[test]
    fn manual_expedited_bytes() {
        // TLC5xx §8.1 / §8.5.
        assert_eq!(
            ClientFrame::InitiateUpload { addr: A }.to_bytes(),
            [0x40, 0, 0x10, 0, 0, 0, 0, 0]
        );
        let resp = ServerFrame::decode(&[0x43, 0x00, 0x10, 0x00, 0x92, 0x01, 0x02, 0x00]).unwrap();
        assert_eq!(
            resp,
            ServerFrame::InitiateUpload {
                addr: A,
                data: InitiateData::Expedited {
                    data: [0x92, 0x01, 0x02, 0x00],
                    len: Some(4)
                }
            }
        );
        let w = ClientFrame::InitiateDownload {
            addr: Address::new(0x6083, 0),
            data: InitiateData::expedited(&2000u32.to_le_bytes()).unwrap(),
        };
        assert_eq!(
            w.to_bytes(),
            [0x23, 0x83, 0x60, 0x00, 0xD0, 0x07, 0x00, 0x00]
        );
        let one = ClientFrame::InitiateDownload {
            addr: Address::new(0x6060, 0),
            data: InitiateData::expedited(&[1]).unwrap(),
        };
        assert_eq!(one.to_bytes()[0], 0x2F);
        assert_eq!(
            ServerFrame::InitiateDownload {
                addr: Address::new(0x6083, 0)
            }
            .to_bytes(),
            [0x60, 0x83, 0x60, 0, 0, 0, 0, 0]
        );
        let abort = ServerFrame::Abort {
            addr: A,
            code: AbortCode::TooShort,
        };
        assert_eq!(abort.to_bytes(), [0x80, 0, 0x10, 0, 0x13, 0x00, 0x07, 0x06]);
    }

    #[test]
    fn expedited_command_bytes_per_length() {
        for (len, cmd) in [(4, 0x23), (3, 0x27), (2, 0x2B), (1, 0x2F)] {
            let f = ClientFrame::InitiateDownload {
                addr: A,
                data: InitiateData::expedited(&[7; 4][..len]).unwrap(),
            };
            assert_eq!(f.to_bytes()[0], cmd);
            assert_eq!(ClientFrame::decode(&f.to_bytes()), Ok(f));
        }
        for (len, cmd) in [(4, 0x43), (3, 0x47), (2, 0x4B), (1, 0x4F)] {
            let f = ServerFrame::InitiateUpload {
                addr: A,
                data: InitiateData::expedited(&[7; 4][..len]).unwrap(),
            };
            assert_eq!(f.to_bytes()[0], cmd);
        }
        assert_eq!(InitiateData::expedited(&[]), None);
        assert_eq!(InitiateData::expedited(&[0; 5]), None);
    }

    #[test]
    fn every_command_round_trips() {
        let seg = Segment::new(true, &[1, 2, 3], true);
        let client = [
            ClientFrame::InitiateDownload {
                addr: A,
                data: InitiateData::Segmented { size: Some(1024) },
            },
            ClientFrame::InitiateDownload {
                addr: A,
                data: InitiateData::Segmented { size: None },
            },
            ClientFrame::InitiateDownload {
                addr: A,
                data: InitiateData::Expedited {
                    data: [1, 2, 3, 4],
                    len: None,
                },
            },
            ClientFrame::DownloadSegment(seg),
            ClientFrame::InitiateUpload { addr: A },
            ClientFrame::UploadSegment { toggle: true },
            ClientFrame::Abort {
                addr: A,
                code: AbortCode::Other(0x0800_1234),
            },
            ClientFrame::BlockDownloadInitiate {
                addr: A,
                crc: true,
                size: Some(4096),
            },
            ClientFrame::BlockDownloadInitiate {
                addr: A,
                crc: false,
                size: None,
            },
            ClientFrame::BlockDownloadEnd {
                unused: 5,
                crc: 0xBEEF,
            },
            ClientFrame::BlockUploadInitiate {
                addr: A,
                crc: true,
                blksize: 127,
                pst: 21,
            },
            ClientFrame::BlockUploadStart,
            ClientFrame::BlockUploadAck {
                ackseq: 0,
                blksize: 1,
            },
            ClientFrame::BlockUploadEnd,
        ];
        for f in client {
            assert_eq!(ClientFrame::decode(&f.to_bytes()), Ok(f), "{f:?}");
        }
        let server = [
            ServerFrame::InitiateUpload {
                addr: A,
                data: InitiateData::Segmented { size: Some(9) },
            },
            ServerFrame::UploadSegment(seg),
            ServerFrame::InitiateDownload { addr: A },
            ServerFrame::DownloadSegment { toggle: true },
            ServerFrame::Abort {
                addr: A,
                code: AbortCode::NoObject,
            },
            ServerFrame::BlockDownloadInitiate {
                addr: A,
                crc: true,
                blksize: 64,
            },
            ServerFrame::BlockDownloadAck {
                ackseq: 127,
                blksize: 127,
            },
            ServerFrame::BlockDownloadEnd,
            ServerFrame::BlockUploadInitiate {
                addr: A,
                crc: true,
                size: Some(77),
            },
            ServerFrame::BlockUploadEnd { unused: 7, crc: 1 },
        ];
        for f in server {
            assert_eq!(ServerFrame::decode(&f.to_bytes()), Ok(f), "{f:?}");
        }
    }

    #[test]
    fn segment_layout() {
        // t=1, n=4 (3 data bytes), c=1: 000 1 100 1.
        let s = Segment::new(true, &[0xAA, 0xBB, 0xCC], true);
        let b = ClientFrame::DownloadSegment(s).to_bytes();
        assert_eq!(b, [0x19, 0xAA, 0xBB, 0xCC, 0, 0, 0, 0]);
        assert_eq!(s.payload(), &[0xAA, 0xBB, 0xCC]);
        // Upload segment request toggles bit 4 only.
        assert_eq!(
            ClientFrame::UploadSegment { toggle: true }.to_bytes()[0],
            0x70
        );
        // Block: last segment 5 is 0x85.
        let bs = BlockSegment::new(5, true, &[9]);
        assert_eq!(bs.to_bytes(), [0x85, 9, 0, 0, 0, 0, 0, 0]);
        assert_eq!(BlockSegment::decode(&bs.to_bytes()), Ok(bs));
        assert_eq!(
            BlockSegment::decode(&[0x80, 0, 0, 0, 0, 0, 0, 0]),
            Err(DecodeError::SeqNo(0))
        );
    }

    #[test]
    fn block_command_bytes() {
        let init = ClientFrame::BlockDownloadInitiate {
            addr: Address::new(0x2000, 1),
            crc: true,
            size: Some(4096),
        };
        assert_eq!(
            init.to_bytes(),
            [0xC6, 0x00, 0x20, 0x01, 0x00, 0x10, 0x00, 0x00]
        );
        assert_eq!(
            ClientFrame::BlockDownloadEnd {
                unused: 3,
                crc: 0x1234
            }
            .to_bytes(),
            [0xCD, 0x34, 0x12, 0, 0, 0, 0, 0]
        );
        let up = ClientFrame::BlockUploadInitiate {
            addr: A,
            crc: true,
            blksize: 127,
            pst: 0,
        };
        assert_eq!(up.to_bytes(), [0xA4, 0x00, 0x10, 0x00, 0x7F, 0, 0, 0]);
        assert_eq!(
            ServerFrame::BlockDownloadAck {
                ackseq: 3,
                blksize: 9
            }
            .to_bytes(),
            [0xA2, 3, 9, 0, 0, 0, 0, 0]
        );
    }

    #[test]
    fn invalid_frames_are_typed_errors() {
        assert_eq!(
            ClientFrame::decode(&[0xE0, 0, 0, 0, 0, 0, 0, 0]),
            Err(DecodeError::UnknownCommand(0xE0))
        );
        assert_eq!(
            ServerFrame::decode(&[0xE0, 0, 0, 0, 0, 0, 0, 0]),
            Err(DecodeError::UnknownCommand(0xE0))
        );
        assert_eq!(
            ServerFrame::decode(&[0xA3, 0, 0, 0, 0, 0, 0, 0]),
            Err(DecodeError::UnknownCommand(0xA3))
        );
        assert_eq!(
            ClientFrame::decode(&[0x40, 0, 0x10]),
            Err(DecodeError::Length(3))
        );
        assert_eq!(
            ClientFrame::decode(&[0xA0, 0, 0x10, 0, 0, 0, 0, 0]),
            Err(DecodeError::BlockSize(0))
        );
        assert_eq!(
            ClientFrame::decode(&[0xA2, 200, 5, 0, 0, 0, 0, 0]),
            Err(DecodeError::AckSeq(200))
        );
        assert_eq!(
            ServerFrame::decode(&[0xA0, 0, 0x10, 0, 128, 0, 0, 0]),
            Err(DecodeError::BlockSize(128))
        );
        let short = Frame::new_std(0x601, &[0x40, 0, 0x10, 0]).unwrap();
        assert_eq!(ClientFrame::from_frame(&short), Err(DecodeError::Length(4)));
        let rtr = Frame::new_std_remote(0x601, 8).unwrap();
        assert_eq!(ClientFrame::from_frame(&rtr), Err(DecodeError::Length(0)));
        assert_eq!(
            DecodeError::UnknownCommand(0xE0).abort_code().code(),
            0x0504_0001
        );
    }

    #[test]
    fn decoders_never_panic() {
        // Every byte 0 with both fill patterns; decoding must return, not panic.
        for c in 0..=255u8 {
            for fill in [0x00, 0xFF] {
                let b = [c, fill, fill, fill, fill, fill, fill, fill];
                let _ = ClientFrame::decode(&b);
                let _ = ServerFrame::decode(&b);
                let _ = BlockSegment::decode(&b);
                if let Ok(f) = ClientFrame::decode(&b) {
                    // Re-encoding keeps the meaning.
                    assert_eq!(ClientFrame::decode(&f.to_bytes()), Ok(f));
                }
            }
        }
    }
}
