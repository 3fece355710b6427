//! Modbus TCP, master (client) side: how the coordinator speaks FHPP to a CMMO-ST.
//!
//! - [`client`]: a sans-I/O, allocation-free client codec: requests FC 0x17 (the cyclic image
//!   exchange), 0x03 and 0x10 (parameter access outside the cycle) with transaction ids, and a
//!   response decoder that checks every field against the request it answers.
//!
//! The device side lives in `sim::cmmo_st` (std only); the two are written independently and
//! tested against each other, so a shared misreading of the wire format does not hide.
//!
//! FHPP bytes travel as big-endian registers (`fhpp::Variant::CmmoSt.default_byte_order()`):
//! FHPP byte k is the k-th register data byte, so an image is sent exactly as its bytes, and
//! [`bytes_to_registers`] / [`registers_to_bytes`] are the only place registers and bytes meet.

pub mod client;

/// Splits big-endian register bytes into registers: `regs[i] = bytes[2i] << 8 | bytes[2i+1]`.
/// Converts `min(bytes.len() / 2, regs.len())` registers and returns that count (an odd last
/// byte is ignored).
pub fn bytes_to_registers(bytes: &[u8], regs: &mut [u16]) -> usize {
    let mut n = 0;
    for (reg, pair) in regs.iter_mut().zip(bytes.chunks_exact(2)) {
        if let [hi, lo] = pair {
            *reg = u16::from_be_bytes([*hi, *lo]);
            n += 1;
        }
    }
    n
}

/// Writes registers as big-endian bytes (high byte first). Converts `min(regs.len(),
/// bytes.len() / 2)` registers and returns how many bytes were written.
pub fn registers_to_bytes(regs: &[u16], bytes: &mut [u8]) -> usize {
    let mut n = 0;
    for (pair, reg) in bytes.chunks_exact_mut(2).zip(regs) {
        pair.copy_from_slice(&reg.to_be_bytes());
        n += 2;
    }
    n
}

/// The 8-byte FHPP image as its 4 registers (register 0 = `CCON << 8 | CPOS`, or SCON/SPOS).
pub fn image_to_registers(image: &[u8; 8]) -> [u16; 4] {
    let mut regs = [0; 4];
    bytes_to_registers(image, &mut regs);
    regs
}

/// 4 registers as the 8-byte FHPP image.
pub fn registers_to_image(regs: &[u16; 4]) -> [u8; 8] {
    let mut image = [0; 8];
    registers_to_bytes(regs, &mut image);
    image
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn register_zero_carries_the_first_two_fhpp_bytes_high_byte_first() {
        // CCON 0x43 (ENABLE, STOP, LOCK), CPOS 0x01 -> register 0 = 0x4301.
        let image = [0x43, 0x01, 0x02, 0x00, 0x12, 0x34, 0x56, 0x78];
        let regs = image_to_registers(&image);
        assert_eq!(regs, [0x4301, 0x0200, 0x1234, 0x5678]);
        assert_eq!(registers_to_image(&regs), image);
    }

    #[test]
    fn conversions_stop_at_the_shorter_side() {
        let mut regs = [0u16; 2];
        assert_eq!(bytes_to_registers(&[1, 2, 3, 4, 5, 6, 7], &mut regs), 2);
        assert_eq!(regs, [0x0102, 0x0304]);
        let mut regs = [0u16; 4];
        assert_eq!(bytes_to_registers(&[1, 2, 3], &mut regs), 1);
        let mut bytes = [0u8; 3];
        assert_eq!(registers_to_bytes(&[0xAABB, 0xCCDD], &mut bytes), 2);
        assert_eq!(bytes, [0xAA, 0xBB, 0]);
    }
}
