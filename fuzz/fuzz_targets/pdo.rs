#![no_main]
//! PDO: any mapping built from fuzzer words either is refused with a typed error or packs and
//! unpacks values identically; unpacking arbitrary frame data never panics.

use drivers::canopen::pdo::{CobId, Mapping, TransmissionType};
use libfuzzer_sys::fuzz_target;

fuzz_target!(|data: &[u8]| {
    if data.len() < 2 {
        return;
    }
    let n = (data[0] % 9) as usize;
    let words: Vec<u32> = data[1..]
        .chunks_exact(4)
        .take(n)
        .map(|c| u32::from_le_bytes([c[0], c[1], c[2], c[3]]))
        .collect();
    let _ = TransmissionType::from_u8(data[1]);
    let _ = CobId::from_u32(words.first().copied().unwrap_or(0)).check();
    let Ok(m) = Mapping::from_raw(&words) else { return };
    let rest = &data[1 + 4 * words.len()..];
    let _ = m.unpack_values(rest);
    let mut values = [0u64; 8];
    for (i, e) in m.entries().iter().enumerate() {
        let bits = e.bits as u32;
        let mask = if bits >= 64 { u64::MAX } else { (1u64 << bits) - 1 };
        values[i] = rest.get(i).copied().unwrap_or(0xA5) as u64 * 0x0101_0101_0101_0101 & mask;
        if e.is_dummy() {
            values[i] = 0;
        }
    }
    let mut out = [0u8; 8];
    let len = m.pack(&values[..m.entries().len()], &mut out);
    let back = m.unpack_values(&out[..len]).expect("own frame unpacks");
    for (i, e) in m.entries().iter().enumerate() {
        if !e.is_dummy() {
            assert_eq!(back.as_slice()[i], values[i]);
        }
    }
});
