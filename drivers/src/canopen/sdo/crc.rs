//! The CRC of SDO block transfer (CiA 301 §7.2.4.3.16): CRC-16-CCITT as XMODEM computes it,
//! polynomial x^16 + x^12 + x^5 + 1 (0x1021), initial value 0, no reflection, no final XOR.

/// One table entry per byte value, built at compile time so the per-byte cost is one lookup.
const TABLE: [u16; 256] = build_table();

const fn build_table() -> [u16; 256] {
    let mut table = [0u16; 256];
    let mut i = 0;
    while i < 256 {
        let mut crc = (i as u16) << 8;
        let mut bit = 0;
        while bit < 8 {
            crc = if crc & 0x8000 != 0 {
                (crc << 1) ^ 0x1021
            } else {
                crc << 1
            };
            bit += 1;
        }
        table[i] = crc;
        i += 1;
    }
    table
}

/// Continues a CRC over `data`. Start with `0` (or use [`crc16`]); feeding the data in pieces
/// gives the same result as feeding it at once, which is how a block upload computes it while
/// it reads the object.
pub fn crc16_update(mut crc: u16, data: &[u8]) -> u16 {
    for &b in data {
        crc = (crc << 8) ^ TABLE[((crc >> 8) as u8 ^ b) as usize];
    }
    crc
}

/// The CRC of `data` as SDO block transfer sends it in the end frame.
pub fn crc16(data: &[u8]) -> u16 {
    crc16_update(0, data)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn check_value() {
        // The catalogue check value of CRC-16/XMODEM.
        assert_eq!(crc16(b"123456789"), 0x31C3);
        assert_eq!(crc16(&[]), 0);
    }

    #[test]
    fn pieces_equal_whole() {
        let data: [u8; 100] = core::array::from_fn(|i| (i * 37 + 11) as u8);
        let whole = crc16(&data);
        let (a, b) = data.split_at(33);
        assert_eq!(crc16_update(crc16(a), b), whole);
    }

    #[test]
    fn table_matches_bitwise() {
        fn bitwise(data: &[u8]) -> u16 {
            let mut crc = 0u16;
            for &b in data {
                crc ^= (b as u16) << 8;
                for _ in 0..8 {
                    crc = if crc & 0x8000 != 0 {
                        (crc << 1) ^ 0x1021
                    } else {
                        crc << 1
                    };
                }
            }
            crc
        }
        let data: [u8; 64] = core::array::from_fn(|i| (i * 91 + 5) as u8);
        assert_eq!(crc16(&data), bitwise(&data));
    }
}
