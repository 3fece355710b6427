//! Helpers shared by the fuzz targets: turning fuzzer bytes into CAN frames.

use drivers::can::Frame;

/// Splits fuzzer input into frames: each frame takes 2 bytes of identifier (11 bits used), one
/// byte of flags (bit 7 RTR, low 4 bits DLC, clamped to 8) and DLC data bytes.
pub fn frames(mut data: &[u8]) -> impl Iterator<Item = Frame> + '_ {
    core::iter::from_fn(move || {
        if data.len() < 3 {
            return None;
        }
        let id = u16::from_le_bytes([data[0], data[1]]) & 0x7FF;
        let flags = data[2];
        let dlc = ((flags & 0x0F) as usize).min(8);
        data = &data[3..];
        if flags & 0x80 != 0 {
            return Frame::new_std_remote(id, dlc as u8).ok();
        }
        let n = dlc.min(data.len());
        let f = Frame::new_std(id, &data[..n]).ok();
        data = &data[n..];
        f
    })
}
