//! The per-cycle output hash: FNV-1a 64 over a fixed byte encoding of what one cycle produced.
//!
//! Written out by hand rather than through `core::hash::Hash`: the derived `Hash` of the core's
//! types feeds `usize` lengths and enum discriminants whose width and order are the compiler's
//! choice, so a 32-bit microcontroller and a 64-bit host could disagree on identical values.
//! Here every field is fed as fixed-width little-endian bytes, in the order written below.

use coordinator::cycle::{AxisStatus, BusFrame, GroupStatus};
use coordinator::records::ChainState;

/// FNV-1a 64 offset basis.
const OFFSET: u64 = 0xcbf2_9ce4_8422_2325;
/// FNV-1a 64 prime.
const PRIME: u64 = 0x0000_0100_0000_01b3;

/// An FNV-1a 64 hash being built.
#[derive(Clone, Copy, Debug)]
pub struct Fnv1a(u64);

impl Default for Fnv1a {
    fn default() -> Self {
        Fnv1a::new()
    }
}

impl Fnv1a {
    /// The empty hash (the offset basis).
    pub const fn new() -> Fnv1a {
        Fnv1a(OFFSET)
    }

    /// Feeds bytes.
    pub fn bytes(&mut self, b: &[u8]) {
        for &x in b {
            self.0 ^= u64::from(x);
            self.0 = self.0.wrapping_mul(PRIME);
        }
    }

    /// Feeds one byte.
    pub fn u8(&mut self, v: u8) {
        self.bytes(&[v]);
    }

    /// Feeds a `u16`, little-endian.
    pub fn u16(&mut self, v: u16) {
        self.bytes(&v.to_le_bytes());
    }

    /// Feeds a `u32`, little-endian.
    pub fn u32(&mut self, v: u32) {
        self.bytes(&v.to_le_bytes());
    }

    /// Feeds a `u64`, little-endian.
    pub fn u64(&mut self, v: u64) {
        self.bytes(&v.to_le_bytes());
    }

    /// Feeds an `i64`, little-endian two's complement.
    pub fn i64(&mut self, v: i64) {
        self.bytes(&v.to_le_bytes());
    }

    /// The hash.
    pub const fn finish(self) -> u64 {
        self.0
    }
}

/// Feeds one sent frame: bus, raw identifier (u32), flags (bit 0 extended, bit 1 remote), DLC,
/// then the data bytes. The timestamp is not fed: a sent frame has none yet.
pub fn frame(h: &mut Fnv1a, f: &BusFrame) {
    h.u8(f.bus);
    h.u32(f.frame.raw_id());
    h.u8(u8::from(f.frame.is_extended()) | u8::from(f.frame.is_remote()) << 1);
    h.u8(f.frame.dlc());
    h.bytes(f.frame.data());
}

/// Feeds one axis's published state: state, position, setpoint, setpoint velocity, the drive's
/// fault number, then one byte of flags (faulted by the coordinator, online, enabled, moving,
/// homed, motion complete) and the activity.
pub fn axis(h: &mut Fnv1a, s: &AxisStatus) {
    h.u8(s.feedback.state as u8);
    h.i64(s.feedback.position);
    h.i64(s.setpoint);
    h.i64(s.setpoint_velocity);
    h.u16(s.feedback.fault_code);
    let flags = u8::from(s.fault != coordinator::fault::FaultReason::None)
        | u8::from(s.online) << 1
        | u8::from(s.enabled) << 2
        | u8::from(s.moving) << 3
        | u8::from(s.feedback.homed) << 4
        | u8::from(s.feedback.motion_complete) << 5;
    h.u8(flags);
    h.u8(s.activity as u8);
}

/// Feeds one group's published state: the chain's state, its record (`FFFFh`: none) and
/// whether a move runs.
pub fn group(h: &mut Fnv1a, s: &GroupStatus) {
    h.u8(chain_state(s.chain.state));
    h.u16(s.chain.record.unwrap_or(u16::MAX));
    h.u8(u8::from(s.motion.is_some()));
}

/// A chain state as a number of our own, fixed here.
fn chain_state(s: ChainState) -> u8 {
    match s {
        ChainState::Idle => 0,
        ChainState::Delay => 1,
        ChainState::Moving => 2,
        ChainState::Waiting => 3,
        ChainState::Complete => 4,
        ChainState::Aborted => 5,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The published FNV-1a 64 test vectors.
    #[test]
    fn fnv1a_64_vectors() {
        let h = |s: &[u8]| {
            let mut f = Fnv1a::new();
            f.bytes(s);
            f.finish()
        };
        assert_eq!(h(b""), 0xcbf2_9ce4_8422_2325);
        assert_eq!(h(b"a"), 0xaf63_dc4c_8601_ec8c);
        assert_eq!(h(b"foobar"), 0x8594_4171_f739_67e8);
    }
}
