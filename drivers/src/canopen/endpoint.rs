//! The shape every sans-I/O CANopen participant shares, so one loop can drive a master, a
//! simulated device or a whole machine of them on any [`Bus`](crate::can::Bus).

use crate::can::Frame;
use crate::time::Instant;

/// A participant on a CAN bus, fed frames and time, returning frames to send.
pub trait Endpoint {
    /// Takes one received frame: every frame on the bus that [`Endpoint::accepts`] lets
    /// through (the endpoint still ignores what is not for it).
    fn handle_frame(&mut self, frame: &Frame, now: Instant);
    /// Whether `frame` can concern this endpoint: the acceptance filter a CAN controller
    /// applies before the stack sees a frame. A loop may leave out a frame this refuses, so it
    /// must refuse only frames that change nothing the endpoint sends or shows. The default
    /// lets every frame through.
    fn accepts(&self, frame: &Frame) -> bool {
        let _ = frame;
        true
    }
    /// The next frame to send at `now`, if any. Called until it returns `None`.
    fn poll_transmit(&mut self, now: Instant) -> Option<Frame>;
    /// When the endpoint next needs [`Endpoint::handle_timeout`] (a timer, a periodic frame).
    fn poll_timeout(&self) -> Option<Instant>;
    /// Runs the timers that are due at `now`.
    fn handle_timeout(&mut self, now: Instant);
}

impl<E: Endpoint + ?Sized> Endpoint for &mut E {
    fn accepts(&self, frame: &Frame) -> bool {
        (**self).accepts(frame)
    }
    fn handle_frame(&mut self, frame: &Frame, now: Instant) {
        (**self).handle_frame(frame, now)
    }
    fn poll_transmit(&mut self, now: Instant) -> Option<Frame> {
        (**self).poll_transmit(now)
    }
    fn poll_timeout(&self) -> Option<Instant> {
        (**self).poll_timeout()
    }
    fn handle_timeout(&mut self, now: Instant) {
        (**self).handle_timeout(now)
    }
}

#[cfg(feature = "std")]
impl<E: Endpoint + ?Sized> Endpoint for Box<E> {
    fn accepts(&self, frame: &Frame) -> bool {
        (**self).accepts(frame)
    }
    fn handle_frame(&mut self, frame: &Frame, now: Instant) {
        (**self).handle_frame(frame, now)
    }
    fn poll_transmit(&mut self, now: Instant) -> Option<Frame> {
        (**self).poll_transmit(now)
    }
    fn poll_timeout(&self) -> Option<Instant> {
        (**self).poll_timeout()
    }
    fn handle_timeout(&mut self, now: Instant) {
        (**self).handle_timeout(now)
    }
}
