//! A segment of subdevices in one process: a frame passes through each in wiring order, as it
//! does through a line of ESCs, and comes back to the master with the source MAC marked.
//!
//! Each subdevice is an [`Esc`] and the application behind it ([`Subdevice`]); after the frame
//! has passed, every application gets its turn (AL control, mailbox, process data), as a
//! drive's firmware would between frames.

use super::esc::Esc;
use super::frame::{Frame, FrameError};
use crate::time::Instant;

/// A subdevice: its ESC and the application behind it.
pub trait Subdevice {
    /// The ESC, for the frame to pass through.
    fn esc(&mut self) -> &mut Esc;
    /// Whether it has power. A frame stops at the first one without: the one before it sees
    /// no link on its port 1, closes the port and sends the frame back (digest §2, DL status).
    fn powered(&self) -> bool {
        true
    }
    /// The application's turn after a frame (and on time passing: `now` may be later than the
    /// last frame's time).
    fn poll(&mut self, now: Instant);
}

/// Marks a processed frame's source MAC: a real ESC sets the locally administered bit of the
/// first byte (digest §1), and masters drop frames whose source is their own address (their
/// raw socket may see what they send).
pub const MAC_MARK: u8 = 0x02;

/// Passes a received frame through the subdevices in order, then gives each its turn; the
/// buffer is then the reply, of the same length.
pub fn pass<S: Subdevice>(
    buf: &mut [u8],
    subdevices: &mut [S],
    now: Instant,
) -> Result<(), FrameError> {
    let mut frame = Frame::parse(buf)?;
    let mut source = frame.source();
    for s in subdevices.iter_mut() {
        if !s.powered() {
            break;
        }
        let esc = s.esc();
        for i in 0..frame.len() {
            esc.process(&mut frame.datagram(i), now);
        }
    }
    source[0] |= MAC_MARK;
    frame.set_source(source);
    for s in subdevices.iter_mut() {
        s.poll(now);
    }
    Ok(())
}
