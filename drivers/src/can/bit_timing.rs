//! How long a frame occupies the bus.
//!
//! The worst-case length counts every possible stuff bit (one after each four equal bits of the
//! stuffed region: SOF through CRC) plus the 3-bit intermission: 135 bits for a standard frame
//! with 8 data bytes, 160 for an extended one. The nominal (unstuffed) length is 111 bits for an
//! 8-byte standard frame. The bus-load budget and the virtual bus both use these numbers.

use core::time::Duration;

/// Lowest bitrate the virtual bus accepts (bit/s).
pub const MIN_BITRATE: u32 = 20_000;
/// Highest bitrate of classic CAN (bit/s).
pub const MAX_BITRATE: u32 = 1_000_000;

/// Unstuffed frame length in bits, including the 3-bit intermission.
pub const fn nominal_bits(extended: bool, data_len: u8) -> u32 {
    let n = data_len as u32 * 8;
    // SOF 1, arbitration 12 (std) / 32 (ext), control 6, data, CRC 16, ACK 2, EOF 7, IFS 3.
    if extended { 67 + n } else { 47 + n }
}

/// Worst-case stuffed frame length in bits, including the 3-bit intermission.
pub const fn worst_case_bits(extended: bool, data_len: u8) -> u32 {
    let n = data_len as u32 * 8;
    // Stuffed region: SOF..CRC = 34 (std) / 54 (ext) bits + data; worst case one stuff bit per
    // 4 bits after the first 5 ("(g + 8n - 1) / 4").
    let stuffed = if extended { 54 + n } else { 34 + n };
    nominal_bits(extended, data_len) + (stuffed - 1) / 4
}

/// Bits on the wire for a frame as actually sent: remote frames carry no data bytes.
pub fn frame_bits(frame: &super::Frame) -> u32 {
    let len = if frame.is_remote() { 0 } else { frame.dlc() };
    worst_case_bits(frame.is_extended(), len)
}

/// The time one bit takes at `bitrate` bit/s, in nanoseconds (rounded up).
pub const fn bit_time_ns(bitrate: u32) -> u64 {
    1_000_000_000u64.div_ceil(bitrate as u64)
}

/// The time `bits` take at `bitrate` bit/s, rounded up to whole nanoseconds.
pub const fn bits_duration(bits: u32, bitrate: u32) -> Duration {
    Duration::from_nanos((bits as u64 * 1_000_000_000).div_ceil(bitrate as u64))
}

/// The worst-case time a frame occupies the bus at `bitrate` bit/s.
pub fn frame_duration(frame: &super::Frame, bitrate: u32) -> Duration {
    bits_duration(frame_bits(frame), bitrate)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn known_lengths() {
        assert_eq!(worst_case_bits(false, 8), 135);
        assert_eq!(nominal_bits(false, 8), 111);
        assert_eq!(worst_case_bits(false, 0), 55);
        assert_eq!(worst_case_bits(true, 8), 160);
        assert_eq!(bits_duration(135, 1_000_000), Duration::from_micros(135));
        assert_eq!(bits_duration(135, 125_000), Duration::from_micros(1080));
    }
}
