//! candump log files, as `candump -l` writes them and python-can's `CanutilsLogReader` reads
//! them: one frame per line, `(SECONDS.MICROS) INTERFACE ID#DATA`.
//!
//! ```text
//! (1700000000.123456) can0 605#4000100000000000
//! (1700000000.123789) vbus:x 12345678#DEADBEEF
//! (1700000000.124000) can0 705#R
//! ```
//!
//! Standard identifiers have 3 hex digits, extended ones 8; remote frames are `ID#R` (with the
//! DLC appended when it is not zero, `ID#R1`). CAN FD (`ID##...`) lines are rejected with a typed
//! error. Anything after the frame (python-can 4 appends a direction flag, ` R` or ` T`) is
//! ignored. Timestamps keep microseconds, so a log read back equals what was written.

use super::{Frame, ParseFrameError};
use crate::time::Instant;
use std::io::{self, BufRead, Write};

/// One line of a candump log.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct LogRecord {
    /// When the frame completed on the bus (microsecond resolution in the file).
    pub timestamp: Instant,
    /// The interface name (`can0`, `vbus:x`).
    pub interface: String,
    /// The frame; its own timestamp equals `timestamp`.
    pub frame: Frame,
}

/// Why a candump log line could not be read.
#[derive(Debug, thiserror::Error)]
pub enum CandumpError {
    /// The line does not start with `(SECONDS.MICROS)`.
    #[error("line {line}: expected a timestamp like (1700000000.123456)")]
    Timestamp {
        /// 1-based line number.
        line: usize,
    },
    /// The interface name or the frame is missing.
    #[error("line {line}: expected `(TIMESTAMP) INTERFACE ID#DATA`")]
    Fields {
        /// 1-based line number.
        line: usize,
    },
    /// A CAN FD frame (`ID##FLAGSDATA`), which classic CAN cannot carry.
    #[error("line {line}: CAN FD frames are not supported")]
    CanFd {
        /// 1-based line number.
        line: usize,
    },
    /// The frame text is malformed.
    #[error("line {line}: {source}")]
    Frame {
        /// 1-based line number.
        line: usize,
        /// What is wrong with it.
        source: ParseFrameError,
    },
    /// Reading the file failed.
    #[error("reading the candump log failed: {0}")]
    Io(#[from] io::Error),
}

/// Formats one log line (without the newline).
pub fn format_line(timestamp: Instant, interface: &str, frame: &Frame) -> String {
    format!("({timestamp}) {interface} {frame}")
}

/// Parses one log line; `line_no` (1-based) goes into errors.
pub fn parse_line(text: &str, line_no: usize) -> Result<LogRecord, CandumpError> {
    let text = text.trim();
    let ts_err = CandumpError::Timestamp { line: line_no };
    let rest = text
        .strip_prefix('(')
        .ok_or(CandumpError::Timestamp { line: line_no })?;
    let (ts, rest) = rest
        .split_once(')')
        .ok_or(CandumpError::Timestamp { line: line_no })?;
    let timestamp = parse_timestamp(ts).ok_or(ts_err)?;
    let mut fields = rest.split_whitespace();
    let (Some(interface), Some(frame_text)) = (fields.next(), fields.next()) else {
        return Err(CandumpError::Fields { line: line_no });
    };
    if frame_text.contains("##") {
        return Err(CandumpError::CanFd { line: line_no });
    }
    let frame: Frame = frame_text.parse().map_err(|source| CandumpError::Frame {
        line: line_no,
        source,
    })?;
    Ok(LogRecord {
        timestamp,
        interface: interface.to_owned(),
        frame: frame.with_timestamp(timestamp),
    })
}

/// `SECONDS.FRACTION` with up to 9 fraction digits (candump writes 6).
fn parse_timestamp(s: &str) -> Option<Instant> {
    let (secs, frac) = s.split_once('.').unwrap_or((s, ""));
    if secs.is_empty() || !secs.bytes().all(|b| b.is_ascii_digit()) || frac.len() > 9 {
        return None;
    }
    if !frac.bytes().all(|b| b.is_ascii_digit()) {
        return None;
    }
    let secs: u64 = secs.parse().ok()?;
    let mut nanos = 0u64;
    for (i, b) in frac.bytes().enumerate() {
        nanos += u64::from(b - b'0') * 10u64.pow(8 - i as u32);
    }
    Some(Instant::from_nanos(
        secs.checked_mul(1_000_000_000)?.checked_add(nanos)?,
    ))
}

/// Writes candump log lines.
#[derive(Debug)]
pub struct CandumpWriter<W: Write> {
    out: W,
}

impl<W: Write> CandumpWriter<W> {
    /// A writer appending to `out`.
    pub fn new(out: W) -> Self {
        CandumpWriter { out }
    }

    /// Writes one line for `frame` seen on `interface` at `timestamp`.
    pub fn write(&mut self, timestamp: Instant, interface: &str, frame: &Frame) -> io::Result<()> {
        writeln!(self.out, "{}", format_line(timestamp, interface, frame))
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

/// Reads a whole candump log; blank lines are skipped.
pub fn read_log<R: BufRead>(input: R) -> Result<Vec<LogRecord>, CandumpError> {
    let mut out = Vec::new();
    for (i, line) in input.lines().enumerate() {
        let line = line?;
        if line.trim().is_empty() {
            continue;
        }
        out.push(parse_line(&line, i + 1)?);
    }
    Ok(out)
}

/// The interactive candump line (`candump IFACE` without `-l`): interface, identifier, `[DLC]`
/// and the data bytes separated by spaces, or `remote request` for RTR frames.
///
/// ```text
///   vbus:x  605   [8]  40 00 10 00 00 00 00 00
///   vbus:x  12345678   [1]  01
///   vbus:x  705   [0]  remote request
/// ```
pub fn format_live(interface: &str, frame: &Frame) -> String {
    let id = if frame.is_extended() {
        format!("{:08X}", frame.raw_id())
    } else {
        format!("{:03X}", frame.raw_id())
    };
    let mut s = format!("  {interface}  {id}   [{}] ", frame.dlc());
    if frame.is_remote() {
        s.push_str(" remote request");
    } else {
        for b in frame.data() {
            s.push_str(&format!(" {b:02X}"));
        }
    }
    s
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn line_round_trip() {
        let t = Instant::from_micros(1_700_000_000_123_456);
        for text in [
            "605#4000100000000000",
            "12345678#DEADBEEF",
            "705#R",
            "705#R1",
            "080#",
        ] {
            let f: Frame = text.parse().unwrap();
            let line = format_line(t, "can0", &f);
            assert_eq!(line, format!("(1700000000.123456) can0 {text}"));
            let r = parse_line(&line, 1).unwrap();
            assert_eq!(r.timestamp, t);
            assert_eq!(r.interface, "can0");
            assert_eq!(r.frame, f);
            assert_eq!(r.frame.timestamp(), t);
        }
    }

    #[test]
    fn errors_name_the_line() {
        let e = parse_line("1700000000.1 can0 123#00", 7).unwrap_err();
        assert!(matches!(e, CandumpError::Timestamp { line: 7 }));
        assert!(e.to_string().starts_with("line 7:"));
        assert!(matches!(
            parse_line("(1.000001) can0", 2),
            Err(CandumpError::Fields { line: 2 })
        ));
        assert!(matches!(
            parse_line("(1.000001) can0 123##1DEAD", 3),
            Err(CandumpError::CanFd { line: 3 })
        ));
        assert!(matches!(
            parse_line("(1.000001) can0 1234#00", 4),
            Err(CandumpError::Frame {
                line: 4,
                source: ParseFrameError::BadId
            })
        ));
        assert!(matches!(
            parse_line("(1.x) can0 123#00", 5),
            Err(CandumpError::Timestamp { line: 5 })
        ));
    }

    #[test]
    fn live_format() {
        let f: Frame = "605#4000".parse().unwrap();
        assert_eq!(format_live("vbus:x", &f), "  vbus:x  605   [2]  40 00");
        let r: Frame = "705#R".parse().unwrap();
        assert_eq!(format_live("can0", &r), "  can0  705   [0]  remote request");
    }

    #[test]
    fn reads_python_can_style_nanosecond_free_timestamps() {
        let r = parse_line("(0.5) vcan0 123#11", 1).unwrap();
        assert_eq!(r.timestamp, Instant::from_millis(500));
    }
}
