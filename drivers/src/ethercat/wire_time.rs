//! How long a cycle's EtherCAT traffic takes on a 100 Mbit/s line: the bytes of the frames a
//! master sends each cycle, on the wire with preamble, FCS and inter-frame gap, and the round
//! trip through the segment's subdevices.
//!
//! The frame a cycle needs is what ethercrab sends (its `tx_rx`): one LRW over the whole
//! process image, one FPRD of AL status (0130h, 2 bytes) per subdevice, and with distributed
//! clocks one FRMW of the system time (0910h, 8 bytes); frames of at most 1514 bytes, as many
//! as the datagrams need. All arithmetic is integer and rounds up.
//!
//! ```
//! use drivers::ethercat::wire_time::{CycleTraffic, round_trip_ns};
//! // Three EMCAs, 32 bytes each way each, with DC.
//! let t = CycleTraffic { image_bytes: 3 * 64, subdevices: 3, dc: true };
//! assert_eq!(t.frames(), 1);
//! assert_eq!(t.frame_bytes(), 14 + 2 + (12 + 8) + (12 + 192) + 3 * (12 + 2));
//! assert_eq!(t.wire_ns(), (8 + t.frame_bytes() as u64 + 4 + 12) * 80);
//! assert_eq!(round_trip_ns(&t), t.wire_ns() + 3 * 1_000);
//! ```

use super::frame::{DATAGRAM_HEADER_LEN, ECAT_HEADER_LEN, ETH_HEADER_LEN, MAX_FRAME_LEN, WKC_LEN};

/// One byte at 100 Mbit/s, in ns.
pub const BYTE_NS: u64 = 80;
/// Preamble and start-of-frame delimiter.
pub const PREAMBLE_BYTES: usize = 8;
/// The frame check sequence.
pub const FCS_BYTES: usize = 4;
/// The inter-frame gap.
pub const GAP_BYTES: usize = 12;
/// The shortest Ethernet frame with its FCS.
pub const MIN_FRAME_WITH_FCS: usize = 64;
/// What one subdevice adds to the round trip, ns: through its port 0, processing unit and
/// port 1 and back. ASSUMED: about 1 µs, the figure usually quoted for a subdevice with two
/// 100BASE-TX PHYs (an EBUS-only device forwards faster); the manual gives none.
pub const SUBDEVICE_DELAY_NS: u64 = 1_000;

/// A datagram's bytes in a frame: header, data, working counter.
const fn datagram(data: usize) -> usize {
    DATAGRAM_HEADER_LEN + data + WKC_LEN
}

/// What one cycle exchanges on a segment.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct CycleTraffic {
    /// The process image: every subdevice's inputs and outputs, bytes.
    pub image_bytes: usize,
    /// Subdevices in the segment (one AL status read each).
    pub subdevices: usize,
    /// Whether the cycle reads the reference clock (FRMW of 0910h).
    pub dc: bool,
}

impl CycleTraffic {
    /// The datagram bytes of one cycle, before they are split into frames.
    fn datagram_bytes(&self) -> usize {
        let dc = if self.dc { datagram(8) } else { 0 };
        dc + datagram(self.image_bytes) + self.subdevices * datagram(2)
    }

    /// The frames the cycle needs (the process image is split across frames when it does not
    /// fit one).
    pub fn frames(&self) -> usize {
        let room = MAX_FRAME_LEN - ETH_HEADER_LEN - ECAT_HEADER_LEN;
        self.datagram_bytes().div_ceil(room).max(1)
    }

    /// The bytes of the cycle's frames from the Ethernet header to the last working counter,
    /// without FCS (as a capture shows them). With more than one frame, each split adds a
    /// datagram header and working counter.
    pub fn frame_bytes(&self) -> usize {
        let frames = self.frames();
        frames * (ETH_HEADER_LEN + ECAT_HEADER_LEN)
            + self.datagram_bytes()
            + (frames - 1) * (DATAGRAM_HEADER_LEN + WKC_LEN)
    }

    /// The time the cycle's frames occupy the line, ns: each frame padded to 64 bytes with its
    /// FCS, plus preamble and inter-frame gap.
    pub fn wire_ns(&self) -> u64 {
        let frames = self.frames();
        let per_frame_overhead = PREAMBLE_BYTES + FCS_BYTES + GAP_BYTES;
        // Padding matters only for a frame shorter than the minimum; with one frame it is exact,
        // with several the split frames are long.
        let body = self.frame_bytes();
        let padded = if frames == 1 {
            (body + FCS_BYTES).max(MIN_FRAME_WITH_FCS) - FCS_BYTES
        } else {
            body
        };
        (padded + frames * per_frame_overhead) as u64 * BYTE_NS
    }
}

/// The round trip of a cycle's frames: their time on the line plus the forwarding delay of
/// every subdevice ([`SUBDEVICE_DELAY_NS`]); cable propagation (5 ns/m) is left out.
pub fn round_trip_ns(t: &CycleTraffic) -> u64 {
    t.wire_ns() + t.subdevices as u64 * SUBDEVICE_DELAY_NS
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_small_frame_is_padded_to_the_ethernet_minimum() {
        let t = CycleTraffic {
            image_bytes: 2,
            subdevices: 0,
            dc: false,
        };
        // 14 + 2 + (10 + 2 + 2) = 30 bytes: padded to 60 + FCS, plus preamble and gap.
        assert_eq!(t.frame_bytes(), 30);
        assert_eq!(t.wire_ns(), (60 + 4 + 8 + 12) * 80);
    }

    #[test]
    fn a_large_image_takes_several_frames() {
        let t = CycleTraffic {
            image_bytes: 3000,
            subdevices: 10,
            dc: true,
        };
        assert_eq!(t.frames(), 3);
        assert!(t.frame_bytes() > 3000 + 10 * 14 + 20);
        // 128 EMCAs of 64 bytes each.
        let big = CycleTraffic {
            image_bytes: 128 * 64,
            subdevices: 128,
            dc: true,
        };
        assert_eq!(big.frames(), 7);
        // 20 + 8204 + 128 × 14 = 10 016 datagram bytes in 7 frames (6 splits of 12 bytes):
        // 10 200 bytes, 10 368 on the line with preamble, FCS and gap (829.44 µs), and 128 µs
        // through the subdevices.
        assert_eq!(big.frame_bytes(), 10_200);
        assert_eq!(round_trip_ns(&big), 829_440 + 128_000);
    }
}
