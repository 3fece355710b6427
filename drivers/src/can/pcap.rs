//! pcap capture files with link type `LINKTYPE_CAN_SOCKETCAN` (227), readable by Wireshark and
//! tshark.
//!
//! File layout (all of it little-endian except the CAN identifier):
//!
//! - global header, 24 bytes: magic `0xA1B2C3D4` (microsecond timestamps), version 2.4, zone 0,
//!   sigfigs 0, snaplen 65535, link type 227;
//! - per frame, a 16-byte record header (seconds, microseconds, captured length 16, original
//!   length 16) and 16 bytes of SocketCAN `struct can_frame`: `can_id` **big-endian** with the
//!   flags EFF `0x8000_0000` and RTR `0x4000_0000`, the payload length (the DLC for remote
//!   frames), 3 bytes of padding/reserved, and 8 data bytes (zero past the length).
//!
//! Wireshark shows raw CAN by default (or a heuristic guess such as AUTOSAR NM). To decode the
//! payload as CANopen, use "Decode As" on the `can.subdissector` table, heuristics second:
//! `tshark -o can.try_heuristic_first:FALSE -d can.subdissector,canopen -r FILE`
//! ([`TSHARK_CANOPEN_ARGS`]; verified with tshark 4.0.17). Note the comma: the table has no
//! selector value, so the `==value` form is rejected.

use super::Frame;
use crate::time::Instant;
use embedded_can::{ExtendedId, Id, StandardId};
use std::io::{self, Write};

/// The pcap link type of SocketCAN frames (`LINKTYPE_CAN_SOCKETCAN`).
pub const LINKTYPE_CAN_SOCKETCAN: u32 = 227;
/// The magic number of a pcap file with microsecond timestamps.
pub const PCAP_MAGIC_MICROS: u32 = 0xA1B2_C3D4;
/// Length of the pcap global header.
pub const GLOBAL_HEADER_LEN: usize = 24;
/// Length of a pcap record header.
pub const RECORD_HEADER_LEN: usize = 16;
/// Length of one SocketCAN `struct can_frame`.
pub const CAN_FRAME_LEN: usize = 16;

/// The extended-frame flag in a SocketCAN `can_id`.
pub const CAN_EFF_FLAG: u32 = 0x8000_0000;
/// The remote-request flag in a SocketCAN `can_id`.
pub const CAN_RTR_FLAG: u32 = 0x4000_0000;
/// The error-frame flag in a SocketCAN `can_id`.
pub const CAN_ERR_FLAG: u32 = 0x2000_0000;

/// The tshark options that decode SocketCAN payloads as CANopen (Wireshark 4.0): "Decode As"
/// CANopen for the CAN sub-dissector, tried before the heuristic dissectors.
pub const TSHARK_CANOPEN_ARGS: [&str; 4] = [
    "-o",
    "can.try_heuristic_first:FALSE",
    "-d",
    "can.subdissector,canopen",
];

/// Why a capture could not be decoded.
#[derive(Debug, Clone, Copy, PartialEq, Eq, thiserror::Error)]
pub enum PcapError {
    /// The input ended inside a header or record.
    #[error("pcap truncated at byte {offset}: need {needed} more bytes")]
    Truncated {
        /// Where the missing part starts.
        offset: usize,
        /// How many bytes are missing.
        needed: usize,
    },
    /// Not a microsecond pcap file.
    #[error("not a microsecond pcap file (magic {0:#010x})")]
    BadMagic(u32),
    /// A link type other than SocketCAN.
    #[error("pcap link type {0} is not LINKTYPE_CAN_SOCKETCAN (227)")]
    LinkType(u32),
    /// A record shorter than a SocketCAN frame.
    #[error("pcap record at byte {offset} holds {len} bytes, a SocketCAN frame needs 16")]
    RecordLength {
        /// Where the record starts.
        offset: usize,
        /// Its captured length.
        len: u32,
    },
    /// An error frame (not a data or remote frame).
    #[error("SocketCAN error frame (can_id {0:#010x})")]
    ErrorFrame(u32),
    /// A payload length above 8.
    #[error("SocketCAN payload length {0} exceeds 8")]
    Length(u8),
}

/// The SocketCAN `can_id` of a frame: the identifier with the EFF and RTR flags.
pub fn socketcan_id(frame: &Frame) -> u32 {
    let mut id = frame.raw_id();
    if frame.is_extended() {
        id |= CAN_EFF_FLAG;
    }
    if frame.is_remote() {
        id |= CAN_RTR_FLAG;
    }
    id
}

/// Builds a frame from a SocketCAN `can_id`, payload length (DLC for remote frames) and data.
pub fn frame_from_socketcan(can_id: u32, len: u8, data: &[u8; 8]) -> Result<Frame, PcapError> {
    if can_id & CAN_ERR_FLAG != 0 {
        return Err(PcapError::ErrorFrame(can_id));
    }
    if len > 8 {
        return Err(PcapError::Length(len));
    }
    // Both masks keep the value in range, so the constructors cannot fail; map anyway.
    let id = if can_id & CAN_EFF_FLAG != 0 {
        Id::Extended(ExtendedId::new(can_id & 0x1FFF_FFFF).ok_or(PcapError::ErrorFrame(can_id))?)
    } else {
        Id::Standard(StandardId::new((can_id & 0x7FF) as u16).ok_or(PcapError::ErrorFrame(can_id))?)
    };
    let frame = if can_id & CAN_RTR_FLAG != 0 {
        Frame::new_remote(id, len)
    } else {
        Frame::new_data(id, data.get(..len as usize).unwrap_or(&[]))
    };
    frame.map_err(|_| PcapError::Length(len))
}

/// Encodes a frame as the 16-byte SocketCAN `struct can_frame` of a pcap record (`can_id`
/// big-endian, as `LINKTYPE_CAN_SOCKETCAN` specifies).
pub fn encode_socketcan(frame: &Frame) -> [u8; CAN_FRAME_LEN] {
    let mut out = [0u8; CAN_FRAME_LEN];
    out[..4].copy_from_slice(&socketcan_id(frame).to_be_bytes());
    out[4] = frame.dlc();
    let data = frame.data();
    out[8..8 + data.len()].copy_from_slice(data);
    out
}

/// Decodes the 16-byte SocketCAN `struct can_frame` of a pcap record.
pub fn decode_socketcan(bytes: &[u8]) -> Result<Frame, PcapError> {
    let b: &[u8; CAN_FRAME_LEN] = bytes
        .get(..CAN_FRAME_LEN)
        .and_then(|s| s.try_into().ok())
        .ok_or(PcapError::Truncated {
            offset: 0,
            needed: CAN_FRAME_LEN.saturating_sub(bytes.len()),
        })?;
    let can_id = u32::from_be_bytes([b[0], b[1], b[2], b[3]]);
    let mut data = [0u8; 8];
    data.copy_from_slice(&b[8..16]);
    frame_from_socketcan(can_id, b[4], &data)
}

/// The pcap link type of Ethernet II frames (`LINKTYPE_ETHERNET`): EtherCAT captures.
pub const LINKTYPE_ETHERNET: u32 = 1;

/// The 24-byte pcap global header of a capture of `linktype` frames.
pub fn global_header_for(linktype: u32) -> [u8; GLOBAL_HEADER_LEN] {
    let mut h = [0u8; GLOBAL_HEADER_LEN];
    h[0..4].copy_from_slice(&PCAP_MAGIC_MICROS.to_le_bytes());
    h[4..6].copy_from_slice(&2u16.to_le_bytes());
    h[6..8].copy_from_slice(&4u16.to_le_bytes());
    // thiszone and sigfigs stay zero.
    h[16..20].copy_from_slice(&65_535u32.to_le_bytes());
    h[20..24].copy_from_slice(&linktype.to_le_bytes());
    h
}

/// The 24-byte pcap global header for SocketCAN captures.
pub fn global_header() -> [u8; GLOBAL_HEADER_LEN] {
    global_header_for(LINKTYPE_CAN_SOCKETCAN)
}

/// A record header for `len` bytes captured whole at `timestamp` (microsecond resolution; the
/// epoch is whatever the caller's clock uses, Wireshark assumes the Unix epoch).
pub fn record_header(timestamp: Instant, len: u32) -> [u8; RECORD_HEADER_LEN] {
    let mut r = [0u8; RECORD_HEADER_LEN];
    let us = timestamp.as_micros();
    // pcap seconds are 32-bit; saturate rather than wrap (year 2106).
    let secs = u32::try_from(us / 1_000_000).unwrap_or(u32::MAX);
    r[0..4].copy_from_slice(&secs.to_le_bytes());
    r[4..8].copy_from_slice(&((us % 1_000_000) as u32).to_le_bytes());
    r[8..12].copy_from_slice(&len.to_le_bytes());
    r[12..16].copy_from_slice(&len.to_le_bytes());
    r
}

/// One complete pcap record (header and SocketCAN frame) for a frame at `timestamp`.
pub fn encode_record(timestamp: Instant, frame: &Frame) -> [u8; RECORD_HEADER_LEN + CAN_FRAME_LEN] {
    let mut r = [0u8; RECORD_HEADER_LEN + CAN_FRAME_LEN];
    r[..RECORD_HEADER_LEN].copy_from_slice(&record_header(timestamp, CAN_FRAME_LEN as u32));
    r[RECORD_HEADER_LEN..].copy_from_slice(&encode_socketcan(frame));
    r
}

/// Writes a pcap capture of CAN frames.
#[derive(Debug)]
pub struct PcapWriter<W: Write> {
    out: W,
}

impl<W: Write> PcapWriter<W> {
    /// Writes the global header and returns the writer.
    pub fn new(mut out: W) -> io::Result<Self> {
        out.write_all(&global_header())?;
        Ok(PcapWriter { out })
    }

    /// Appends one frame captured at `timestamp`.
    pub fn write(&mut self, timestamp: Instant, frame: &Frame) -> io::Result<()> {
        self.out.write_all(&encode_record(timestamp, frame))
    }

    /// Flushes the underlying writer.
    pub fn flush(&mut self) -> io::Result<()> {
        self.out.flush()
    }

    /// Returns the underlying writer.
    pub fn into_inner(self) -> W {
        self.out
    }
}

fn le32(bytes: &[u8], offset: usize) -> Result<u32, PcapError> {
    let b = bytes.get(offset..offset + 4).ok_or(PcapError::Truncated {
        offset,
        needed: (offset + 4).saturating_sub(bytes.len()),
    })?;
    Ok(u32::from_le_bytes([b[0], b[1], b[2], b[3]]))
}

/// Decodes a whole SocketCAN pcap capture into `(timestamp, frame)` pairs; the frames carry the
/// timestamp too.
pub fn read_pcap(bytes: &[u8]) -> Result<Vec<(Instant, Frame)>, PcapError> {
    let magic = le32(bytes, 0)?;
    if magic != PCAP_MAGIC_MICROS {
        return Err(PcapError::BadMagic(magic));
    }
    let link = le32(bytes, 20)?;
    if link != LINKTYPE_CAN_SOCKETCAN {
        return Err(PcapError::LinkType(link));
    }
    let mut out = Vec::new();
    let mut pos = GLOBAL_HEADER_LEN;
    while pos < bytes.len() {
        let secs = le32(bytes, pos)? as u64;
        let micros = le32(bytes, pos + 4)? as u64;
        let incl = le32(bytes, pos + 8)?;
        let body = pos + RECORD_HEADER_LEN;
        if (incl as usize) < CAN_FRAME_LEN {
            return Err(PcapError::RecordLength {
                offset: pos,
                len: incl,
            });
        }
        let end = body.saturating_add(incl as usize);
        let rec = bytes.get(body..end).ok_or(PcapError::Truncated {
            offset: body,
            needed: end.saturating_sub(bytes.len()),
        })?;
        let t = Instant::from_micros(secs * 1_000_000 + micros);
        out.push((t, decode_socketcan(rec)?.with_timestamp(t)));
        pos = end;
    }
    Ok(out)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn record_layout_matches_linktype_227() {
        let f = Frame::new_std(0x605, &[0x40, 0x00, 0x10, 0x00]).unwrap();
        let r = encode_record(Instant::from_micros(1_700_000_000_123_456), &f);
        assert_eq!(&r[0..4], &1_700_000_000u32.to_le_bytes());
        assert_eq!(&r[4..8], &123_456u32.to_le_bytes());
        assert_eq!(&r[8..16], &[16, 0, 0, 0, 16, 0, 0, 0]);
        assert_eq!(&r[16..20], &[0x00, 0x00, 0x06, 0x05]);
        assert_eq!(&r[20..24], &[4, 0, 0, 0]);
        assert_eq!(&r[24..32], &[0x40, 0, 0x10, 0, 0, 0, 0, 0]);

        let ext = Frame::new_ext(0x1234_5678, &[1]).unwrap();
        assert_eq!(&encode_socketcan(&ext)[..4], &[0x92, 0x34, 0x56, 0x78]);
        let rtr = Frame::new_std_remote(0x705, 1).unwrap();
        let e = encode_socketcan(&rtr);
        assert_eq!(&e[..5], &[0x40, 0x00, 0x07, 0x05, 1]);
        assert_eq!(decode_socketcan(&e), Ok(rtr));
    }

    #[test]
    fn global_header_bytes() {
        let h = global_header();
        assert_eq!(&h[..8], &[0xD4, 0xC3, 0xB2, 0xA1, 2, 0, 4, 0]);
        assert_eq!(&h[20..], &[227, 0, 0, 0]);
    }

    #[test]
    fn decoder_rejects_bad_input_without_panicking() {
        assert!(matches!(
            read_pcap(&[1, 2]),
            Err(PcapError::Truncated { .. })
        ));
        let mut bad = global_header().to_vec();
        bad[20] = 1;
        assert_eq!(read_pcap(&bad), Err(PcapError::LinkType(1)));
        let mut f = global_header().to_vec();
        f.extend_from_slice(&encode_record(
            Instant::ZERO,
            &Frame::new_std(1, &[]).unwrap(),
        ));
        f.truncate(f.len() - 3);
        assert!(matches!(read_pcap(&f), Err(PcapError::Truncated { .. })));
        let mut long = [0u8; 16];
        long[4] = 9;
        assert_eq!(decode_socketcan(&long), Err(PcapError::Length(9)));
        long[0] = 0x20;
        assert!(matches!(
            decode_socketcan(&long),
            Err(PcapError::ErrorFrame(_))
        ));
    }
}
