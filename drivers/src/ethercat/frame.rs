//! EtherCAT frames and datagrams (ETG.1000.4; digest §1): the Ethernet II header with EtherType
//! 88A4h, the 2-byte EtherCAT header, and a chain of datagrams, each a 10-byte header, its data
//! and a 2-byte working counter. All fields are little-endian except the EtherType.
//!
//! A subdevice works on a frame in place: [`Frame::parse`] finds the datagrams of a received
//! buffer, and each [`Datagram`] gives its data and working counter to change as the frame
//! passes through. [`FrameBuilder`] writes a frame (a master's, or a test's).
//!
//! ```
//! use drivers::ethercat::frame::{Command, Frame, FrameBuilder};
//! let mut buf = [0u8; 64];
//! let mut b = FrameBuilder::new(&mut buf, [0x10; 6]).unwrap();
//! b.push(Command::Brd, 7, 0x0000_0000, &[0, 0]).unwrap();
//! let len = b.finish();
//! assert_eq!(len, 60); // padded to the Ethernet minimum
//! let mut frame = Frame::parse(&mut buf[..len]).unwrap();
//! assert_eq!(frame.len(), 1);
//! let dg = frame.datagram(0);
//! assert_eq!((dg.command(), dg.idx(), dg.wkc()), (Some(Command::Brd), 7, 0));
//! ```

/// The EtherType of EtherCAT (big-endian on the wire).
pub const ETHERTYPE: u16 = 0x88A4;
/// Destination, source and EtherType.
pub const ETH_HEADER_LEN: usize = 14;
/// The EtherCAT header: length and type.
pub const ECAT_HEADER_LEN: usize = 2;
/// A datagram's header: command, index, address, length and flags, IRQ.
pub const DATAGRAM_HEADER_LEN: usize = 10;
/// The working counter after a datagram's data.
pub const WKC_LEN: usize = 2;
/// The shortest Ethernet frame without its FCS: shorter frames are padded to it.
pub const MIN_FRAME_LEN: usize = 60;
/// The longest Ethernet frame without its FCS.
pub const MAX_FRAME_LEN: usize = 1514;
/// The most datagram data one frame can carry (the EtherCAT header's 11-bit length field and
/// the Ethernet payload both bound it).
pub const MAX_DATAGRAMS_LEN: usize = MAX_FRAME_LEN - ETH_HEADER_LEN - ECAT_HEADER_LEN;
/// The most datagrams [`Frame::parse`] accepts in one frame (each takes at least 12 bytes).
pub const MAX_DATAGRAMS: usize = MAX_DATAGRAMS_LEN / (DATAGRAM_HEADER_LEN + WKC_LEN);
/// The EtherCAT header's type for datagrams (the only one a subdevice processes).
pub const TYPE_DATAGRAMS: u8 = 1;

/// The "more datagrams follow" flag in a datagram's length word.
const MORE: u16 = 0x8000;
/// The "circulated" flag in a datagram's length word.
const CIRCULATED: u16 = 0x4000;
/// The data length in a datagram's length word.
const LEN_MASK: u16 = 0x07FF;

/// A datagram's command (digest §1, "Commands").
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
#[repr(u8)]
pub enum Command {
    /// No operation: every subdevice passes it on untouched.
    Nop = 0,
    /// Auto-increment physical read: the subdevice that sees position 0.
    Aprd = 1,
    /// Auto-increment physical write.
    Apwr = 2,
    /// Auto-increment physical read-write.
    Aprw = 3,
    /// Configured-address physical read.
    Fprd = 4,
    /// Configured-address physical write.
    Fpwr = 5,
    /// Configured-address physical read-write.
    Fprw = 6,
    /// Broadcast read: every subdevice ORs its bytes into the data.
    Brd = 7,
    /// Broadcast write.
    Bwr = 8,
    /// Broadcast read-write.
    Brw = 9,
    /// Logical read, through the FMMUs.
    Lrd = 10,
    /// Logical write.
    Lwr = 11,
    /// Logical read-write.
    Lrw = 12,
    /// Auto-increment read, multiple write: the addressed subdevice reads, the others write.
    Armw = 13,
    /// Configured-address read, multiple write.
    Frmw = 14,
}

/// How a command addresses subdevices.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Addressing {
    /// Nobody.
    None,
    /// By position: the subdevice that sees ADP 0; every subdevice increments ADP.
    Position,
    /// By configured station address (register 0010h) or alias.
    Station,
    /// Every subdevice.
    Broadcast,
    /// By logical address, through the FMMUs.
    Logical,
}

impl Command {
    /// The command for a code byte, if it is one.
    pub const fn from_code(code: u8) -> Option<Command> {
        use Command::*;
        Some(match code {
            0 => Nop,
            1 => Aprd,
            2 => Apwr,
            3 => Aprw,
            4 => Fprd,
            5 => Fpwr,
            6 => Fprw,
            7 => Brd,
            8 => Bwr,
            9 => Brw,
            10 => Lrd,
            11 => Lwr,
            12 => Lrw,
            13 => Armw,
            14 => Frmw,
            _ => return None,
        })
    }

    /// How the command addresses subdevices.
    pub const fn addressing(self) -> Addressing {
        use Command::*;
        match self {
            Nop => Addressing::None,
            Aprd | Apwr | Aprw | Armw => Addressing::Position,
            Fprd | Fpwr | Fprw | Frmw => Addressing::Station,
            Brd | Bwr | Brw => Addressing::Broadcast,
            Lrd | Lwr | Lrw => Addressing::Logical,
        }
    }

    /// Whether the addressed subdevice copies its memory into the data.
    pub const fn reads(self) -> bool {
        use Command::*;
        matches!(
            self,
            Aprd | Aprw | Fprd | Fprw | Brd | Brw | Lrd | Lrw | Armw | Frmw
        )
    }

    /// Whether the addressed subdevice copies the data into its memory.
    pub const fn writes(self) -> bool {
        use Command::*;
        matches!(self, Apwr | Aprw | Fpwr | Fprw | Bwr | Brw | Lwr | Lrw)
    }

    /// The short name ETG.1000 gives it (for captures and messages).
    pub const fn name(self) -> &'static str {
        use Command::*;
        match self {
            Nop => "NOP",
            Aprd => "APRD",
            Apwr => "APWR",
            Aprw => "APRW",
            Fprd => "FPRD",
            Fpwr => "FPWR",
            Fprw => "FPRW",
            Brd => "BRD",
            Bwr => "BWR",
            Brw => "BRW",
            Lrd => "LRD",
            Lwr => "LWR",
            Lrw => "LRW",
            Armw => "ARMW",
            Frmw => "FRMW",
        }
    }
}

/// Why a buffer is not an EtherCAT frame a subdevice can process.
#[derive(Debug, Clone, Copy, PartialEq, Eq, thiserror::Error)]
pub enum FrameError {
    /// Shorter than the Ethernet and EtherCAT headers.
    #[error("frame of {0} bytes is shorter than the Ethernet and EtherCAT headers")]
    TooShort(usize),
    /// Another EtherType.
    #[error("EtherType {0:#06x} is not EtherCAT (0x88a4)")]
    NotEtherCat(u16),
    /// An EtherCAT header of another type than datagrams.
    #[error("EtherCAT header type {0} is not datagrams (1)")]
    NotDatagrams(u8),
    /// A datagram runs past the end of the frame.
    #[error("datagram {index} at byte {offset} runs past the end of the frame")]
    Truncated {
        /// Which datagram (0-based).
        index: usize,
        /// Where its header starts in the frame.
        offset: usize,
    },
    /// More datagrams than [`MAX_DATAGRAMS`].
    #[error("more than {MAX_DATAGRAMS} datagrams in one frame")]
    TooManyDatagrams,
    /// The buffer cannot hold what is being added.
    #[error("the frame has no room for {needed} more bytes")]
    NoRoom {
        /// Bytes the addition needs.
        needed: usize,
    },
}

/// A received EtherCAT frame with its datagrams located, to be worked on in place.
#[derive(Debug)]
pub struct Frame<'a> {
    buf: &'a mut [u8],
    /// Byte offset of each datagram's header.
    starts: heapless::Vec<u16, MAX_DATAGRAMS>,
}

impl<'a> Frame<'a> {
    /// Locates the datagrams of a frame (Ethernet header first). Bytes after the last
    /// datagram (the padding) are left alone.
    pub fn parse(buf: &'a mut [u8]) -> Result<Frame<'a>, FrameError> {
        if buf.len() < ETH_HEADER_LEN + ECAT_HEADER_LEN {
            return Err(FrameError::TooShort(buf.len()));
        }
        let ethertype = u16::from_be_bytes([buf[12], buf[13]]);
        if ethertype != ETHERTYPE {
            return Err(FrameError::NotEtherCat(ethertype));
        }
        let header = le16(buf, ETH_HEADER_LEN);
        let kind = (header >> 12) as u8;
        if kind != TYPE_DATAGRAMS {
            return Err(FrameError::NotDatagrams(kind));
        }
        let mut starts = heapless::Vec::new();
        let mut at = ETH_HEADER_LEN + ECAT_HEADER_LEN;
        loop {
            let index = starts.len();
            if at + DATAGRAM_HEADER_LEN + WKC_LEN > buf.len() {
                return Err(FrameError::Truncated { index, offset: at });
            }
            let word = le16(buf, at + 6);
            let end = at + DATAGRAM_HEADER_LEN + usize::from(word & LEN_MASK) + WKC_LEN;
            if end > buf.len() {
                return Err(FrameError::Truncated { index, offset: at });
            }
            starts
                .push(at as u16)
                .map_err(|_| FrameError::TooManyDatagrams)?;
            if word & MORE == 0 {
                break;
            }
            at = end;
        }
        Ok(Frame { buf, starts })
    }

    /// The number of datagrams.
    pub fn len(&self) -> usize {
        self.starts.len()
    }

    /// Whether the frame has no datagram (never, once parsed).
    pub fn is_empty(&self) -> bool {
        self.starts.is_empty()
    }

    /// The source MAC address.
    pub fn source(&self) -> [u8; 6] {
        let mut mac = [0; 6];
        mac.copy_from_slice(&self.buf[6..12]);
        mac
    }

    /// Sets the source MAC address (a subdevice marks a frame it processed: digest §1).
    pub fn set_source(&mut self, mac: [u8; 6]) {
        self.buf[6..12].copy_from_slice(&mac);
    }

    /// Datagram `i` (0-based), to read and change in place.
    ///
    /// # Panics
    /// If `i` is not below [`Frame::len`].
    pub fn datagram(&mut self, i: usize) -> Datagram<'_> {
        let start = usize::from(self.starts[i]);
        let len = usize::from(le16(self.buf, start + 6) & LEN_MASK);
        let end = start + DATAGRAM_HEADER_LEN + len + WKC_LEN;
        Datagram {
            raw: &mut self.buf[start..end],
        }
    }

    /// The whole buffer.
    pub fn bytes(&self) -> &[u8] {
        self.buf
    }
}

/// One datagram of a frame: its header fields, data and working counter, in place.
#[derive(Debug)]
pub struct Datagram<'a> {
    /// Header, data and working counter.
    raw: &'a mut [u8],
}

impl Datagram<'_> {
    /// The command, if the code is one.
    pub fn command(&self) -> Option<Command> {
        Command::from_code(self.raw[0])
    }

    /// The command byte as sent.
    pub fn command_code(&self) -> u8 {
        self.raw[0]
    }

    /// The index the master gave it (returned unchanged).
    pub fn idx(&self) -> u8 {
        self.raw[1]
    }

    /// The 32-bit address field: a logical address, or ADP (low half) and ADO (high half).
    pub fn address(&self) -> u32 {
        u32::from_le_bytes([self.raw[2], self.raw[3], self.raw[4], self.raw[5]])
    }

    /// ADP: the position (auto-increment) or the configured station address.
    pub fn adp(&self) -> u16 {
        le16(self.raw, 2)
    }

    /// Sets ADP (a subdevice increments it as a position-addressed datagram passes).
    pub fn set_adp(&mut self, adp: u16) {
        self.raw[2..4].copy_from_slice(&adp.to_le_bytes());
    }

    /// ADO: the register or memory offset inside the subdevice.
    pub fn ado(&self) -> u16 {
        le16(self.raw, 4)
    }

    /// Whether another datagram follows in the frame.
    pub fn more(&self) -> bool {
        le16(self.raw, 6) & MORE != 0
    }

    /// Whether the datagram has circulated (passed the segment's end once).
    pub fn circulated(&self) -> bool {
        le16(self.raw, 6) & CIRCULATED != 0
    }

    /// The data.
    pub fn data(&self) -> &[u8] {
        let end = self.raw.len() - WKC_LEN;
        &self.raw[DATAGRAM_HEADER_LEN..end]
    }

    /// The data, to change in place.
    pub fn data_mut(&mut self) -> &mut [u8] {
        let end = self.raw.len() - WKC_LEN;
        &mut self.raw[DATAGRAM_HEADER_LEN..end]
    }

    /// The working counter.
    pub fn wkc(&self) -> u16 {
        le16(self.raw, self.raw.len() - WKC_LEN)
    }

    /// Sets the working counter.
    pub fn set_wkc(&mut self, wkc: u16) {
        let at = self.raw.len() - WKC_LEN;
        self.raw[at..].copy_from_slice(&wkc.to_le_bytes());
    }

    /// Adds to the working counter (wrapping, as the 16-bit counter of an ESC does).
    pub fn add_wkc(&mut self, n: u16) {
        self.set_wkc(self.wkc().wrapping_add(n));
    }
}

/// Writes an EtherCAT frame into a buffer: Ethernet header (broadcast destination), EtherCAT
/// header, then datagrams; [`FrameBuilder::finish`] pads to 60 bytes and returns the length.
#[derive(Debug)]
pub struct FrameBuilder<'a> {
    buf: &'a mut [u8],
    at: usize,
    /// Where the last datagram's length word is, to set its "more" flag when another follows.
    last: Option<usize>,
}

impl<'a> FrameBuilder<'a> {
    /// A frame from `source` to every station.
    pub fn new(buf: &'a mut [u8], source: [u8; 6]) -> Result<FrameBuilder<'a>, FrameError> {
        if buf.len() < MIN_FRAME_LEN {
            return Err(FrameError::NoRoom {
                needed: MIN_FRAME_LEN - buf.len(),
            });
        }
        buf[..6].copy_from_slice(&[0xFF; 6]);
        buf[6..12].copy_from_slice(&source);
        buf[12..14].copy_from_slice(&ETHERTYPE.to_be_bytes());
        Ok(FrameBuilder {
            buf,
            at: ETH_HEADER_LEN + ECAT_HEADER_LEN,
            last: None,
        })
    }

    /// Appends a datagram with working counter 0; returns its number in the frame.
    pub fn push(
        &mut self,
        command: Command,
        idx: u8,
        address: u32,
        data: &[u8],
    ) -> Result<usize, FrameError> {
        let size = DATAGRAM_HEADER_LEN + data.len() + WKC_LEN;
        let limit = self.buf.len().min(MAX_FRAME_LEN);
        if self.at + size > limit || data.len() > usize::from(LEN_MASK) {
            return Err(FrameError::NoRoom {
                needed: self.at + size - limit.min(self.at + size),
            });
        }
        if let Some(prev) = self.last {
            let word = le16(self.buf, prev) | MORE;
            self.buf[prev..prev + 2].copy_from_slice(&word.to_le_bytes());
        }
        let at = self.at;
        let b = &mut self.buf[at..at + size];
        b[0] = command as u8;
        b[1] = idx;
        b[2..6].copy_from_slice(&address.to_le_bytes());
        b[6..8].copy_from_slice(&(data.len() as u16).to_le_bytes());
        b[8..10].copy_from_slice(&[0, 0]);
        b[DATAGRAM_HEADER_LEN..DATAGRAM_HEADER_LEN + data.len()].copy_from_slice(data);
        b[size - 2..].copy_from_slice(&[0, 0]);
        self.last = Some(at + 6);
        self.at += size;
        let count = self.count();
        Ok(count - 1)
    }

    fn count(&self) -> usize {
        // Walk the chain written so far (a handful of datagrams).
        let mut n = 0;
        let mut at = ETH_HEADER_LEN + ECAT_HEADER_LEN;
        while at < self.at {
            n += 1;
            at += DATAGRAM_HEADER_LEN + usize::from(le16(self.buf, at + 6) & LEN_MASK) + WKC_LEN;
        }
        n
    }

    /// Writes the EtherCAT header, pads to the Ethernet minimum and returns the frame's length.
    pub fn finish(self) -> usize {
        let len = (self.at - ETH_HEADER_LEN - ECAT_HEADER_LEN) as u16;
        let header = (len & LEN_MASK) | (u16::from(TYPE_DATAGRAMS) << 12);
        self.buf[ETH_HEADER_LEN..ETH_HEADER_LEN + 2].copy_from_slice(&header.to_le_bytes());
        let end = self.at.max(MIN_FRAME_LEN);
        self.buf[self.at..end].fill(0);
        end
    }
}

/// A little-endian u16 at `at`.
pub(crate) fn le16(b: &[u8], at: usize) -> u16 {
    u16::from_le_bytes([b[at], b[at + 1]])
}

#[cfg(test)]
mod tests {
    use super::*;

    fn two_datagrams(buf: &mut [u8]) -> usize {
        let mut b = FrameBuilder::new(buf, [0x10; 6]).unwrap();
        assert_eq!(b.push(Command::Aprd, 1, 0x0130_0000, &[0; 2]), Ok(0));
        assert_eq!(b.push(Command::Lrw, 2, 0x0001_0000, &[1, 2, 3, 4]), Ok(1));
        b.finish()
    }

    #[test]
    fn a_built_frame_parses_back_with_its_fields() {
        let mut buf = [0u8; 128];
        let len = two_datagrams(&mut buf);
        assert_eq!(len, 60);
        // EtherCAT header: 12 + 2 + 12 + 4 = 30 bytes of datagrams, type 1.
        assert_eq!(le16(&buf, 14), 30 | 0x1000);
        let mut f = Frame::parse(&mut buf[..len]).unwrap();
        assert_eq!(f.len(), 2);
        assert_eq!(f.source(), [0x10; 6]);
        let d = f.datagram(0);
        assert_eq!(d.command(), Some(Command::Aprd));
        assert_eq!((d.adp(), d.ado(), d.more()), (0, 0x0130, true));
        let mut d = f.datagram(1);
        assert_eq!(
            (d.command(), d.idx(), d.address()),
            (Some(Command::Lrw), 2, 0x0001_0000)
        );
        assert!(!d.more());
        assert_eq!(d.data(), &[1, 2, 3, 4]);
        d.data_mut()[0] = 9;
        d.add_wkc(3);
        assert_eq!(d.wkc(), 3);
        assert_eq!(f.datagram(1).data(), &[9, 2, 3, 4]);
    }

    #[test]
    fn bad_frames_are_refused_with_the_reason() {
        let mut buf = [0u8; 128];
        let len = two_datagrams(&mut buf);
        assert_eq!(
            Frame::parse(&mut buf[..10]).unwrap_err(),
            FrameError::TooShort(10)
        );
        let mut other = buf;
        other[12] = 0x08;
        other[13] = 0x00;
        assert_eq!(
            Frame::parse(&mut other[..len]).unwrap_err(),
            FrameError::NotEtherCat(0x0800)
        );
        let mut mailbox = buf;
        mailbox[15] = 0x50; // type 5
        assert_eq!(
            Frame::parse(&mut mailbox[..len]).unwrap_err(),
            FrameError::NotDatagrams(5)
        );
        // The second datagram claims more data than the frame holds.
        // The first datagram (2 data bytes) takes 14 bytes, so the second starts at 30.
        let mut long = buf;
        long[30 + 6] = 0xFF;
        assert_eq!(
            Frame::parse(&mut long[..len]).unwrap_err(),
            FrameError::Truncated {
                index: 1,
                offset: 30
            }
        );
    }

    #[test]
    fn every_command_code_round_trips_and_others_are_none() {
        for code in 0..=255u8 {
            match Command::from_code(code) {
                Some(c) => assert_eq!(c as u8, code),
                None => assert!(code > 14),
            }
        }
        assert!(Command::Lrw.reads() && Command::Lrw.writes());
        assert!(Command::Frmw.reads() && !Command::Frmw.writes());
        assert_eq!(Command::Bwr.addressing(), Addressing::Broadcast);
    }

    proptest::proptest! {
        #[test]
        fn parsing_never_panics_on_any_bytes(bytes in proptest::collection::vec(0u8..=255, 0..200)) {
            let mut b = bytes.clone();
            if let Ok(mut f) = Frame::parse(&mut b) {
                for i in 0..f.len() {
                    let d = f.datagram(i);
                    let _ = (d.command(), d.data().len(), d.wkc());
                }
            }
        }
    }
}
