//! pcap captures of EtherCAT traffic: whole Ethernet frames, link type `LINKTYPE_ETHERNET` (1),
//! which Wireshark and tshark decode as EtherCAT by the EtherType (88A4h) with no option. The
//! file format (headers, timestamps) is [`crate::can::pcap`]'s.
//!
//! ```
//! use drivers::ethercat::frame::{Command, FrameBuilder};
//! use drivers::ethercat::pcap::EcPcapWriter;
//! use drivers::time::Instant;
//! let mut buf = [0u8; 64];
//! let mut b = FrameBuilder::new(&mut buf, [0x10; 6]).unwrap();
//! b.push(Command::Brd, 0, 0, &[0, 0]).unwrap();
//! let n = b.finish();
//! let mut w = EcPcapWriter::new(Vec::new()).unwrap();
//! w.write(Instant::from_micros(5), &buf[..n]).unwrap();
//! let bytes = w.into_inner();
//! assert_eq!(bytes.len(), 24 + 16 + 60);
//! assert_eq!(&bytes[20..24], &1u32.to_le_bytes()); // Ethernet
//! ```

use crate::can::pcap::{LINKTYPE_ETHERNET, global_header_for, record_header};
use crate::time::Instant;
use std::io::{self, Write};

/// Writes a pcap capture of Ethernet frames.
#[derive(Debug)]
pub struct EcPcapWriter<W: Write> {
    out: W,
}

impl<W: Write> EcPcapWriter<W> {
    /// Writes the global header and returns the writer.
    pub fn new(mut out: W) -> io::Result<Self> {
        out.write_all(&global_header_for(LINKTYPE_ETHERNET))?;
        Ok(EcPcapWriter { out })
    }

    /// Appends one frame (Ethernet header first) seen at `timestamp`.
    pub fn write(&mut self, timestamp: Instant, frame: &[u8]) -> io::Result<()> {
        self.out
            .write_all(&record_header(timestamp, frame.len() as u32))?;
        self.out.write_all(frame)
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
