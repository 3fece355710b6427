//! The drives' side: the project's no_std simulators of the MTR-DCI and the EMCA (FHPP over
//! CANopen), fed the frames the cycle sent and run up to the next SYNC.
//!
//! The bus between them is ideal: every frame arrives at the instant it was sent, in the order
//! sent, and the drives do not hear each other (nothing in this machine listens to another
//! drive). The host's virtual bus models bit timing and arbitration; that model is std
//! (threads, locks) and is not what this scenario checks.

use coordinator::cycle::BusFrame;
use drivers::canopen::NodeId;
use drivers::canopen::endpoint::Endpoint;
use drivers::sim::emca::Emca;
use drivers::sim::mtr_dci::{MtrDci, Profile};
use drivers::time::{Instant, earliest};

use crate::{BUS, X_NODE, Y_NODE};

/// The two simulated drives: x an MTR-DCI, y an EMCA, both in FHPP, on bus 0.
#[derive(Debug)]
pub struct Drives {
    x: MtrDci,
    y: Emca,
}

impl Drives {
    /// Both drives powered on at time zero (their boot-ups queued).
    pub fn new() -> Drives {
        let node = |n| NodeId::new(n).expect("node-IDs of the scenario are valid");
        Drives {
            x: MtrDci::new(node(X_NODE), Profile::Fhpp, Instant::ZERO)
                .expect("the default MTR-DCI builds"),
            y: Emca::new(node(Y_NODE), Instant::ZERO).expect("the default EMCA builds"),
        }
    }

    /// Delivers one frame the coordinator sent, at `now`, to every drive.
    pub fn receive(&mut self, f: &BusFrame, now: Instant) {
        self.x.handle_frame(&f.frame, now);
        self.y.handle_frame(&f.frame, now);
    }

    /// Runs the drives from `from` to just before `until`: what they send at once, then each
    /// timer in turn (their internal cycles, guarding, EMCY inhibit) with what it makes them
    /// send. Every frame goes to `out` stamped with the instant it was sent.
    pub fn run(&mut self, from: Instant, until: Instant, out: &mut impl FnMut(BusFrame)) {
        let mut t = from;
        loop {
            while let Some(f) = self.x.poll_transmit(t) {
                out(BusFrame::new(BUS, f.with_timestamp(t)));
            }
            while let Some(f) = self.y.poll_transmit(t) {
                out(BusFrame::new(BUS, f.with_timestamp(t)));
            }
            let Some(next) = earliest([self.x.poll_timeout(), self.y.poll_timeout()]) else {
                return;
            };
            if next >= until {
                return;
            }
            t = t.max(next);
            if self.x.poll_timeout().is_some_and(|d| d <= t) {
                self.x.handle_timeout(t);
            }
            if self.y.poll_timeout().is_some_and(|d| d <= t) {
                self.y.handle_timeout(t);
            }
        }
    }
}

impl Default for Drives {
    fn default() -> Self {
        Drives::new()
    }
}
