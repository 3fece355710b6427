//! The one CAN frame type: standard (11-bit) and extended (29-bit) identifiers, data and remote
//! (RTR) frames, DLC 0..8, and the time at which the frame completed on the bus.

use crate::time::Instant;
use embedded_can::{ExtendedId, Id, StandardId};

/// Why a frame could not be built or decoded.
#[derive(Debug, Clone, Copy, PartialEq, Eq, thiserror::Error)]
pub enum FrameError {
    /// A standard identifier above 0x7FF.
    #[error("standard CAN identifier {0:#x} exceeds 0x7FF")]
    StandardIdRange(u32),
    /// An extended identifier above 0x1FFF_FFFF.
    #[error("extended CAN identifier {0:#x} exceeds 0x1FFFFFFF")]
    ExtendedIdRange(u32),
    /// More than 8 data bytes (classic CAN).
    #[error("a classic CAN frame carries at most 8 data bytes, not {0}")]
    DataLength(usize),
}

/// A classic CAN frame with its receive (or transmit-completion) timestamp.
///
/// The timestamp is not part of equality: two frames are equal when they would look the same on
/// the wire.
#[derive(Debug, Clone, Copy)]
pub struct Frame {
    id: Id,
    rtr: bool,
    dlc: u8,
    data: [u8; 8],
    timestamp: Instant,
}

impl PartialEq for Frame {
    fn eq(&self, other: &Self) -> bool {
        self.id == other.id
            && self.rtr == other.rtr
            && self.data() == other.data()
            && self.dlc == other.dlc
    }
}
impl Eq for Frame {}

impl Frame {
    /// A data frame with a standard (11-bit) identifier.
    #[inline]
    pub fn new_std(id: u16, data: &[u8]) -> Result<Frame, FrameError> {
        let sid = StandardId::new(id).ok_or(FrameError::StandardIdRange(id as u32))?;
        Self::new_data(Id::Standard(sid), data)
    }

    /// A data frame with an extended (29-bit) identifier.
    pub fn new_ext(id: u32, data: &[u8]) -> Result<Frame, FrameError> {
        let eid = ExtendedId::new(id).ok_or(FrameError::ExtendedIdRange(id))?;
        Self::new_data(Id::Extended(eid), data)
    }

    /// A data frame with any identifier.
    #[inline]
    pub fn new_data(id: Id, data: &[u8]) -> Result<Frame, FrameError> {
        if data.len() > 8 {
            return Err(FrameError::DataLength(data.len()));
        }
        let mut buf = [0u8; 8];
        buf[..data.len()].copy_from_slice(data);
        Ok(Frame {
            id,
            rtr: false,
            dlc: data.len() as u8,
            data: buf,
            timestamp: Instant::ZERO,
        })
    }

    /// A remote (RTR) frame requesting `dlc` bytes.
    pub fn new_remote(id: Id, dlc: u8) -> Result<Frame, FrameError> {
        if dlc > 8 {
            return Err(FrameError::DataLength(dlc as usize));
        }
        Ok(Frame {
            id,
            rtr: true,
            dlc,
            data: [0; 8],
            timestamp: Instant::ZERO,
        })
    }

    /// A remote (RTR) frame with a standard identifier (node guarding polls use these).
    pub fn new_std_remote(id: u16, dlc: u8) -> Result<Frame, FrameError> {
        let sid = StandardId::new(id).ok_or(FrameError::StandardIdRange(id as u32))?;
        Self::new_remote(Id::Standard(sid), dlc)
    }

    /// An 8-byte standard data frame. For protocol code whose identifiers are valid by
    /// construction (COB-IDs below 0x800); an identifier above 0x7FF is masked to 11 bits.
    pub fn std8(id: u16, data: [u8; 8]) -> Frame {
        let sid = StandardId::new(id & 0x7FF).unwrap_or(StandardId::ZERO);
        Frame {
            id: Id::Standard(sid),
            rtr: false,
            dlc: 8,
            data,
            timestamp: Instant::ZERO,
        }
    }

    /// The identifier.
    pub fn id(&self) -> Id {
        self.id
    }
    /// The identifier as a plain number (11 or 29 bits).
    pub fn raw_id(&self) -> u32 {
        match self.id {
            Id::Standard(s) => s.as_raw() as u32,
            Id::Extended(e) => e.as_raw(),
        }
    }
    /// The 11-bit identifier of a standard frame (a CANopen COB-ID), `None` for extended frames.
    #[inline]
    pub fn cob_id(&self) -> Option<u16> {
        match self.id {
            Id::Standard(s) => Some(s.as_raw()),
            Id::Extended(_) => None,
        }
    }
    /// Whether the identifier is extended (29-bit).
    pub fn is_extended(&self) -> bool {
        matches!(self.id, Id::Extended(_))
    }
    /// Whether this is a remote (RTR) frame.
    pub fn is_remote(&self) -> bool {
        self.rtr
    }
    /// The data length code, 0..=8.
    pub fn dlc(&self) -> u8 {
        self.dlc
    }
    /// The data bytes (empty for remote frames).
    #[inline]
    pub fn data(&self) -> &[u8] {
        if self.rtr {
            &[]
        } else {
            &self.data[..self.dlc as usize]
        }
    }
    /// The data as a zero-padded 8-byte array.
    pub fn data8(&self) -> [u8; 8] {
        self.data
    }
    /// When the frame completed on the bus (receive timestamp); zero if never sent.
    pub fn timestamp(&self) -> Instant {
        self.timestamp
    }
    /// The same frame with its timestamp set.
    pub fn with_timestamp(mut self, t: Instant) -> Frame {
        self.timestamp = t;
        self
    }
    /// Sets the timestamp in place.
    pub fn set_timestamp(&mut self, t: Instant) {
        self.timestamp = t;
    }
    /// Mutable access to the data bytes (fault injection corrupts frames this way).
    pub fn data_mut(&mut self) -> &mut [u8] {
        let n = if self.rtr { 0 } else { self.dlc as usize };
        &mut self.data[..n]
    }

    /// The arbitration key: the lower key wins. Standard before extended with the same base
    /// identifier, data before remote with the same identifier (ISO 11898-1 arbitration field).
    pub fn arbitration_key(&self) -> u64 {
        // Lay out the arbitration field as transmitted: 11 base bits, SRR/RTR, IDE, 18 ext bits,
        // RTR. Dominant (0) wins, so a numerically smaller key wins.
        match self.id {
            Id::Standard(s) => {
                let base = s.as_raw() as u64;
                // base(11) | RTR | IDE=0 | (no extension: treat as 0s, then RTR 0)
                (base << 21) | ((self.rtr as u64) << 20)
            }
            Id::Extended(e) => {
                let raw = e.as_raw() as u64;
                let base = raw >> 18;
                let ext = raw & 0x3FFFF;
                // SRR and IDE are recessive (1) for extended frames.
                (base << 21) | (1 << 20) | (1 << 19) | (ext << 1) | (self.rtr as u64)
            }
        }
    }
}

impl core::fmt::Display for Frame {
    /// The candump / cansend notation: `123#DEADBEEF`, `12345678#00`, `701#R`, `701#R1`.
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        match self.id {
            Id::Standard(s) => write!(f, "{:03X}#", s.as_raw())?,
            Id::Extended(e) => write!(f, "{:08X}#", e.as_raw())?,
        }
        if self.rtr {
            f.write_str("R")?;
            if self.dlc > 0 {
                write!(f, "{}", self.dlc)?;
            }
            return Ok(());
        }
        for b in self.data() {
            write!(f, "{b:02X}")?;
        }
        Ok(())
    }
}

/// Why a `cansend`-style frame text could not be parsed.
#[derive(Debug, Clone, Copy, PartialEq, Eq, thiserror::Error)]
pub enum ParseFrameError {
    /// No `#` between identifier and data.
    #[error("expected ID#DATA (for example 605#4000100000000000)")]
    MissingHash,
    /// The identifier is not 3 (standard) or 8 (extended) hex digits.
    #[error("the identifier must be 3 hex digits (standard) or 8 (extended)")]
    BadId,
    /// The data is not an even number of hex digits (dots allowed between bytes).
    #[error("the data must be pairs of hex digits")]
    BadData,
    /// The frame itself is invalid.
    #[error(transparent)]
    Frame(#[from] FrameError),
}

impl core::str::FromStr for Frame {
    type Err = ParseFrameError;
    /// Parses the `cansend` notation: `123#DEADBEEF`, `1F334455#11.22`, `123#R`, `123#R3`.
    fn from_str(s: &str) -> Result<Frame, ParseFrameError> {
        let (id, data) = s
            .trim()
            .split_once('#')
            .ok_or(ParseFrameError::MissingHash)?;
        let raw = u32::from_str_radix(id, 16).map_err(|_| ParseFrameError::BadId)?;
        let ident = match id.len() {
            3 => Id::Standard(StandardId::new(raw as u16).ok_or(FrameError::StandardIdRange(raw))?),
            8 => Id::Extended(ExtendedId::new(raw).ok_or(FrameError::ExtendedIdRange(raw))?),
            _ => return Err(ParseFrameError::BadId),
        };
        if let Some(rest) = data.strip_prefix('R') {
            let dlc = if rest.is_empty() {
                0
            } else {
                rest.parse::<u8>().map_err(|_| ParseFrameError::BadData)?
            };
            return Ok(Frame::new_remote(ident, dlc)?);
        }
        let mut buf = [0u8; 8];
        let mut n = 0usize;
        let mut hi: Option<u8> = None;
        for c in data.chars() {
            if c == '.' {
                if hi.is_some() {
                    return Err(ParseFrameError::BadData);
                }
                continue;
            }
            let v = c.to_digit(16).ok_or(ParseFrameError::BadData)? as u8;
            match hi.take() {
                None => hi = Some(v),
                Some(h) => {
                    if n == 8 {
                        return Err(FrameError::DataLength(9).into());
                    }
                    buf[n] = (h << 4) | v;
                    n += 1;
                }
            }
        }
        if hi.is_some() {
            return Err(ParseFrameError::BadData);
        }
        Ok(Frame::new_data(ident, &buf[..n])?)
    }
}

impl embedded_can::Frame for Frame {
    fn new(id: impl Into<Id>, data: &[u8]) -> Option<Self> {
        Frame::new_data(id.into(), data).ok()
    }
    fn new_remote(id: impl Into<Id>, dlc: usize) -> Option<Self> {
        u8::try_from(dlc)
            .ok()
            .and_then(|d| Frame::new_remote(id.into(), d).ok())
    }
    fn is_extended(&self) -> bool {
        Frame::is_extended(self)
    }
    fn is_remote_frame(&self) -> bool {
        self.rtr
    }
    fn id(&self) -> Id {
        self.id
    }
    fn dlc(&self) -> usize {
        self.dlc as usize
    }
    fn data(&self) -> &[u8] {
        Frame::data(self)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use core::str::FromStr;

    #[test]
    fn builds_and_checks_ranges() {
        assert_eq!(
            Frame::new_std(0x800, &[]),
            Err(FrameError::StandardIdRange(0x800))
        );
        assert_eq!(
            Frame::new_ext(0x2000_0000, &[]),
            Err(FrameError::ExtendedIdRange(0x2000_0000))
        );
        assert_eq!(Frame::new_std(0x1, &[0; 9]), Err(FrameError::DataLength(9)));
        let f = Frame::new_std(0x605, &[0x40, 0, 0x10, 0]).unwrap();
        assert_eq!(f.dlc(), 4);
        assert_eq!(f.data(), &[0x40, 0, 0x10, 0]);
        assert_eq!(f.cob_id(), Some(0x605));
    }

    #[test]
    fn text_round_trip() {
        for s in [
            "605#4000100000000000",
            "080#",
            "12345678#DEADBEEF",
            "704#R",
            "704#R1",
        ] {
            let f = Frame::from_str(s).unwrap();
            assert_eq!(f.to_string(), s);
        }
        assert_eq!(Frame::from_str("123#11.22").unwrap().data(), &[0x11, 0x22]);
        assert_eq!(Frame::from_str("123"), Err(ParseFrameError::MissingHash));
        assert_eq!(Frame::from_str("12#00"), Err(ParseFrameError::BadId));
        assert_eq!(Frame::from_str("123#0"), Err(ParseFrameError::BadData));
        assert!(Frame::from_str("123#000000000000000000").is_err());
    }

    #[test]
    fn arbitration_orders_like_the_wire() {
        let sync = Frame::new_std(0x080, &[]).unwrap();
        let pdo = Frame::new_std(0x181, &[1]).unwrap();
        let rtr = Frame::new_std_remote(0x080, 0).unwrap();
        let ext = Frame::new_ext(0x080 << 18, &[]).unwrap();
        assert!(sync.arbitration_key() < pdo.arbitration_key());
        assert!(sync.arbitration_key() < rtr.arbitration_key());
        assert!(sync.arbitration_key() < ext.arbitration_key());
        // An extended frame whose base id is lower wins over a higher standard id.
        let ext_low = Frame::new_ext(0x07F << 18, &[]).unwrap();
        assert!(ext_low.arbitration_key() < sync.arbitration_key());
    }

    #[test]
    fn equality_ignores_timestamp() {
        let a = Frame::new_std(1, &[1]).unwrap();
        assert_eq!(a, a.with_timestamp(Instant::from_millis(3)));
    }
}
