//! PDO mapping (1600h.. for RPDOs, 1A00h.. for TPDOs) and bit-granular packing.
//!
//! A mapping entry is the 32-bit value `index << 16 | sub << 8 | bits`. Entries are laid out
//! one after another from bit 0 of byte 0, each value little-endian and least significant bit
//! first (CiA 301 §7.4.7.1), so an entry may start and end anywhere inside a byte. Because a
//! classic CAN PDO holds at most 64 bits, the whole frame is one little-endian `u64` and every
//! entry is a shift and a mask.

use crate::canopen::od::{DataType, ObjectDictionary, TypeClass, le_u64};
use crate::canopen::{AbortCode, Address};

/// The most entries one mapping holds. CiA 301 allows up to 64 (one-bit entries); this stack
/// keeps 8, which every drive in the reference manuals uses, so a mapping stays 40 bytes.
pub const MAX_ENTRIES: usize = 8;
/// The most bits a classic CAN PDO carries.
pub const MAX_BITS: u32 = 64;

/// One mapping entry: which object, and how many bits of it.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Default)]
pub struct MappingEntry {
    /// The mapped object (index 0001h..0007h: a dummy entry that fills bits without an object).
    pub addr: Address,
    /// The length in bits, 1..=64.
    pub bits: u8,
}

impl MappingEntry {
    /// `index:sub`, `bits` long.
    pub const fn new(index: u16, sub: u8, bits: u8) -> Self {
        MappingEntry {
            addr: Address::new(index, sub),
            bits,
        }
    }
    /// Decodes the mapping-object value `index << 16 | sub << 8 | bits`.
    pub const fn from_u32(v: u32) -> Self {
        MappingEntry {
            addr: Address::new((v >> 16) as u16, (v >> 8) as u8),
            bits: v as u8,
        }
    }
    /// The mapping-object value.
    pub const fn to_u32(self) -> u32 {
        (self.addr.index as u32) << 16 | (self.addr.sub as u32) << 8 | self.bits as u32
    }
    /// Whether this is a dummy entry (index 0001h..0007h, a data type index): its bits are sent
    /// as zero and ignored on reception.
    pub const fn is_dummy(self) -> bool {
        DataType::is_dummy_index(self.addr.index)
    }
}

/// Why a mapping is refused.
#[derive(Debug, Clone, Copy, PartialEq, Eq, thiserror::Error)]
pub enum MappingError {
    /// More than 8 entries.
    #[error("a PDO maps at most {MAX_ENTRIES} entries, not {count}")]
    TooManyEntries {
        /// The entries asked for.
        count: usize,
    },
    /// The entries add up to more than 64 bits (SDO abort 0604 0042h).
    #[error("the mapped entries add up to {bits} bits, more than the 64 of a CAN frame")]
    TooManyBits {
        /// The total length asked for.
        bits: u32,
    },
    /// An entry of length zero.
    #[error("mapping entry {position} ({addr}) has length 0")]
    ZeroLength {
        /// 1-based position (the mapping sub-index).
        position: u8,
        /// The entry's object.
        addr: Address,
    },
    /// The dictionary refuses an entry (missing object, not mappable, wrong direction, longer
    /// than the object).
    #[error("mapping entry {position} ({addr}) refused: {code}")]
    Object {
        /// 1-based position (the mapping sub-index).
        position: u8,
        /// The entry's object.
        addr: Address,
        /// The abort code an SDO write of this entry gets.
        code: AbortCode,
    },
}

impl MappingError {
    /// The SDO abort code a device answers for this refusal.
    pub const fn abort_code(&self) -> AbortCode {
        match self {
            MappingError::TooManyEntries { .. } | MappingError::TooManyBits { .. } => {
                AbortCode::PdoLength
            }
            MappingError::ZeroLength { .. } => AbortCode::NotMappable,
            MappingError::Object { code, .. } => *code,
        }
    }
}

/// Why received PDO data could not be unpacked.
#[derive(Debug, Clone, Copy, PartialEq, Eq, thiserror::Error)]
pub enum PdoError {
    /// The frame carries fewer bytes than the mapping needs (CiA 301: EMCY 8210h on a device).
    #[error(
        "PDO too short: the mapping needs {expected_bits} bits, the frame has {got_bytes} bytes"
    )]
    TooShort {
        /// The mapping's total length.
        expected_bits: u8,
        /// The received data length.
        got_bytes: usize,
    },
    /// Storing an unpacked value in the dictionary failed.
    #[error("PDO entry {addr} not stored: {code}")]
    Store {
        /// The mapped object.
        addr: Address,
        /// Why the dictionary refused.
        code: AbortCode,
    },
}

/// The values of one PDO, one per mapping entry, each in the low bits of a `u64` (a process
/// image slot). Signed values are kept as their two's-complement bits; see [`sign_extend`].
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Hash)]
pub struct PdoValues {
    /// The values, index = mapping position - 1.
    pub values: [u64; MAX_ENTRIES],
    /// How many are used.
    pub len: u8,
}

impl PdoValues {
    /// The used values.
    pub fn as_slice(&self) -> &[u64] {
        self.values.get(..self.len as usize).unwrap_or(&[])
    }
}

/// Sign-extends the low `bits` bits of `v` (a signed entry unpacked from a PDO).
pub const fn sign_extend(v: u64, bits: u8) -> i64 {
    if bits == 0 || bits >= 64 {
        v as i64
    } else {
        let shift = 64 - bits as u32;
        ((v << shift) as i64) >> shift
    }
}

const fn mask(bits: u8) -> u64 {
    if bits >= 64 {
        u64::MAX
    } else {
        (1u64 << bits) - 1
    }
}

/// Where a mapping's objects were found in a dictionary, entry by entry (`u16::MAX`: not yet
/// looked up): a PDO engine keeps these beside its mapping so that its frames do not search the
/// dictionary again. A stale position is only tried and then replaced.
pub type Positions = [u16; MAX_ENTRIES];

/// A validated PDO mapping: up to 8 entries, at most 64 bits in total.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Default)]
pub struct Mapping {
    entries: [MappingEntry; MAX_ENTRIES],
    count: u8,
    bits: u8,
}

impl Mapping {
    /// The empty mapping (sub00 = 0: the PDO carries no data).
    pub const EMPTY: Mapping = Mapping {
        entries: [MappingEntry::new(0, 0, 0); MAX_ENTRIES],
        count: 0,
        bits: 0,
    };

    /// A mapping of `entries`, checked for count, zero lengths and the 64-bit total.
    pub fn new(entries: &[MappingEntry]) -> Result<Mapping, MappingError> {
        if entries.len() > MAX_ENTRIES {
            return Err(MappingError::TooManyEntries {
                count: entries.len(),
            });
        }
        let mut m = Mapping::EMPTY;
        let mut total = 0u32;
        for (i, e) in entries.iter().enumerate() {
            if e.bits == 0 {
                return Err(MappingError::ZeroLength {
                    position: i as u8 + 1,
                    addr: e.addr,
                });
            }
            total += e.bits as u32;
            m.entries[i] = *e;
        }
        if total > MAX_BITS {
            return Err(MappingError::TooManyBits { bits: total });
        }
        m.count = entries.len() as u8;
        m.bits = total as u8;
        Ok(m)
    }

    /// A mapping from the raw values of sub01..subNN.
    pub fn from_raw(raw: &[u32]) -> Result<Mapping, MappingError> {
        if raw.len() > MAX_ENTRIES {
            return Err(MappingError::TooManyEntries { count: raw.len() });
        }
        let mut e = [MappingEntry::default(); MAX_ENTRIES];
        for (d, r) in e.iter_mut().zip(raw) {
            *d = MappingEntry::from_u32(*r);
        }
        Mapping::new(&e[..raw.len()])
    }

    /// Reads the mapping record at `index` (sub00 = count, sub01.. = entries) from a
    /// dictionary.
    pub fn from_od<const N: usize, const B: usize>(
        od: &ObjectDictionary<'_, N, B>,
        index: u16,
    ) -> Result<Mapping, MappingError> {
        let read = |sub: u8| {
            let addr = Address::new(index, sub);
            od.get_u32(addr).map_err(|code| MappingError::Object {
                position: sub,
                addr,
                code,
            })
        };
        let count = read(0)? as usize;
        if count > MAX_ENTRIES {
            return Err(MappingError::TooManyEntries { count });
        }
        let mut raw = [0u32; MAX_ENTRIES];
        for (i, r) in raw.iter_mut().enumerate().take(count) {
            *r = read(i as u8 + 1)?;
        }
        Mapping::from_raw(&raw[..count])
    }

    /// The entries, in frame order.
    pub fn entries(&self) -> &[MappingEntry] {
        self.entries.get(..self.count as usize).unwrap_or(&[])
    }
    /// The number of entries (the value of sub00).
    pub const fn len(&self) -> usize {
        self.count as usize
    }
    /// Whether nothing is mapped.
    pub const fn is_empty(&self) -> bool {
        self.count == 0
    }
    /// The total length in bits.
    pub const fn total_bits(&self) -> u8 {
        self.bits
    }
    /// The frame length in bytes (DLC).
    pub const fn byte_len(&self) -> usize {
        (self.bits as usize).div_ceil(8)
    }

    /// Packs `values` (one per entry, only the low `bits` of each used; missing values and
    /// dummy entries are zero) into `out`; returns the frame length in bytes.
    pub fn pack(&self, values: &[u64], out: &mut [u8; 8]) -> usize {
        let mut word = 0u64;
        let mut offset = 0u32;
        for (i, e) in self.entries().iter().enumerate() {
            let v = if e.is_dummy() {
                0
            } else {
                values.get(i).copied().unwrap_or(0)
            };
            // offset + bits <= 64 and bits >= 1, so offset < 64.
            word |= (v & mask(e.bits)) << offset;
            offset += e.bits as u32;
        }
        *out = word.to_le_bytes();
        self.byte_len()
    }

    /// Unpacks frame `data` into `values` (one per entry, zero-extended; dummy entries give 0).
    /// Extra bytes beyond the mapping are ignored; missing ones are an error and leave `values`
    /// untouched.
    pub fn unpack(&self, data: &[u8], values: &mut [u64]) -> Result<(), PdoError> {
        if data.len() < self.byte_len() {
            return Err(PdoError::TooShort {
                expected_bits: self.bits,
                got_bytes: data.len(),
            });
        }
        let word = le_u64(data);
        let mut offset = 0u32;
        for (i, e) in self.entries().iter().enumerate() {
            let v = if e.is_dummy() {
                0
            } else {
                (word >> offset) & mask(e.bits)
            };
            if let Some(slot) = values.get_mut(i) {
                *slot = v;
            }
            offset += e.bits as u32;
        }
        Ok(())
    }

    /// [`Mapping::unpack`] into a [`PdoValues`].
    pub fn unpack_values(&self, data: &[u8]) -> Result<PdoValues, PdoError> {
        let mut v = PdoValues {
            len: self.count,
            ..PdoValues::default()
        };
        self.unpack(data, &mut v.values)?;
        Ok(v)
    }

    /// Checks every entry against a dictionary as a device does when the mapping is written:
    /// the object exists (0602 0000h), is mappable in this direction (0604 0041h, from the
    /// PDO-mappable flag and `rwr`/`rww`) and is at least as long as the entry (0604 0041h).
    /// Dummy entries are always accepted.
    pub fn validate<const N: usize, const B: usize>(
        &self,
        od: &ObjectDictionary<'_, N, B>,
        transmit: bool,
    ) -> Result<(), MappingError> {
        for (i, e) in self.entries().iter().enumerate() {
            if e.is_dummy() {
                continue;
            }
            let err = |code| MappingError::Object {
                position: i as u8 + 1,
                addr: e.addr,
                code,
            };
            let def = od.entry(e.addr).map_err(|_| err(AbortCode::NoObject))?;
            let direction = if transmit {
                def.access.tpdo_direction()
            } else {
                def.access.rpdo_direction()
            };
            if !def.pdo_mappable || !direction {
                return Err(err(AbortCode::NotMappable));
            }
            // An entry longer than its object (or of a variable-length object) cannot be
            // mapped either; CANopenNode answers the same code.
            match def.data_type.size() {
                Some(size) if e.bits as usize <= size * 8 => {}
                _ => return Err(err(AbortCode::NotMappable)),
            }
        }
        Ok(())
    }

    /// Packs the current values of the mapped objects (a device's TPDO). Entries longer than
    /// their object were refused by [`Mapping::validate`]; here they read as zero-extended.
    pub fn pack_from_od<const N: usize, const B: usize>(
        &self,
        od: &ObjectDictionary<'_, N, B>,
        out: &mut [u8; 8],
    ) -> Result<usize, MappingError> {
        self.pack_from_od_at(od, out, &mut [u16::MAX; MAX_ENTRIES])
    }

    /// [`Mapping::pack_from_od`], trying the entries' positions in `at` first and keeping
    /// them there (a TPDO packs the same objects on every SYNC).
    pub fn pack_from_od_at<const N: usize, const B: usize>(
        &self,
        od: &ObjectDictionary<'_, N, B>,
        out: &mut [u8; 8],
        at: &mut Positions,
    ) -> Result<usize, MappingError> {
        let mut values = [0u64; MAX_ENTRIES];
        for (i, ((e, v), hint)) in self
            .entries()
            .iter()
            .zip(values.iter_mut())
            .zip(at.iter_mut())
            .enumerate()
        {
            if e.is_dummy() {
                continue;
            }
            let p = od
                .locate_hinted(e.addr, hint)
                .map_err(|code| MappingError::Object {
                    position: i as u8 + 1,
                    addr: e.addr,
                    code,
                })?;
            *v = le_u64(od.raw_at(p));
        }
        Ok(self.pack(&values, out))
    }

    /// Stores unpacked values into the mapped objects (a device's RPDO, when it applies).
    /// Signed entries shorter than their type are sign-extended. Stops at the first refusal.
    pub fn store_into_od<const N: usize, const B: usize>(
        &self,
        values: &[u64],
        od: &mut ObjectDictionary<'_, N, B>,
    ) -> Result<(), PdoError> {
        self.store_into_od_at(values, od, &mut [u16::MAX; MAX_ENTRIES])
    }

    /// [`Mapping::store_into_od`], trying the entries' positions in `at` first and keeping
    /// them there (an RPDO stores into the same objects on every frame).
    pub fn store_into_od_at<const N: usize, const B: usize>(
        &self,
        values: &[u64],
        od: &mut ObjectDictionary<'_, N, B>,
        at: &mut Positions,
    ) -> Result<(), PdoError> {
        for ((e, v), hint) in self.entries().iter().zip(values).zip(at.iter_mut()) {
            if e.is_dummy() {
                continue;
            }
            let store = |code| PdoError::Store { addr: e.addr, code };
            // One lookup for the definition and the write.
            let i = od.locate_hinted(e.addr, hint).map_err(store)?;
            let def = od.entry_at(i);
            let size = def.storage_size().min(8);
            let raw = if def.data_type.class() == TypeClass::Signed {
                sign_extend(*v, e.bits) as u64
            } else {
                *v
            };
            let bytes = raw.to_le_bytes();
            od.set_raw_at(i, bytes.get(..size).unwrap_or(&[]))
                .map_err(store)?;
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::canopen::od::{AccessType, EntryDef};
    use proptest::prelude::*;

    #[test]
    fn entry_value_layout() {
        let e = MappingEntry::from_u32(0x6040_0010);
        assert_eq!(e, MappingEntry::new(0x6040, 0, 16));
        assert_eq!(e.to_u32(), 0x6040_0010);
        assert_eq!(
            MappingEntry::from_u32(0x1018_0220).addr,
            Address::new(0x1018, 2)
        );
        assert!(MappingEntry::new(0x0005, 0, 8).is_dummy());
        assert!(!MappingEntry::new(0x0008, 0, 8).is_dummy());
    }

    #[test]
    fn refuses_bad_mappings() {
        let e = MappingEntry::new(0x6040, 0, 16);
        assert_eq!(
            Mapping::new(&[e; 9]),
            Err(MappingError::TooManyEntries { count: 9 })
        );
        let r = Mapping::from_raw(&[0x6040_0010, 0x607A_0020, 0x60FF_0020]);
        assert_eq!(r, Err(MappingError::TooManyBits { bits: 80 }));
        assert_eq!(r.unwrap_err().abort_code(), AbortCode::PdoLength);
        assert_eq!(
            Mapping::from_raw(&[0x6040_0010, 0x6041_0000]),
            Err(MappingError::ZeroLength {
                position: 2,
                addr: Address::new(0x6041, 0)
            })
        );
        assert!(Mapping::new(&[MappingEntry::new(0x2000, 1, 1); 8]).is_ok());
        assert!(Mapping::new(&[MappingEntry::new(0x2000, 1, 64)]).is_ok());
    }

    #[test]
    fn tlc_rpdo2_bytes() {
        // TLC5xx R_PDO2: controlword 16 bits then target position 32 bits.
        let m = Mapping::from_raw(&[0x6040_0010, 0x607A_0020]).unwrap();
        let mut out = [0u8; 8];
        let n = m.pack(&[0x001F, (-2i32) as u32 as u64], &mut out);
        assert_eq!(n, 6);
        assert_eq!(out[..6], [0x1F, 0x00, 0xFE, 0xFF, 0xFF, 0xFF]);
        let v = m.unpack_values(&out[..6]).unwrap();
        assert_eq!(v.as_slice(), &[0x001F, 0xFFFF_FFFE]);
        assert_eq!(sign_extend(v.values[1], 32), -2);
    }

    #[test]
    fn bits_not_byte_aligned() {
        // 1-bit flag, 3-bit dummy, 12-bit value, 24-bit signed value, 1-bit flag.
        let m = Mapping::new(&[
            MappingEntry::new(0x2000, 1, 1),
            MappingEntry::new(0x0005, 0, 3),
            MappingEntry::new(0x2000, 2, 12),
            MappingEntry::new(0x2000, 3, 24),
            MappingEntry::new(0x2000, 4, 1),
        ])
        .unwrap();
        assert_eq!(m.total_bits(), 41);
        assert_eq!(m.byte_len(), 6);
        let mut out = [0u8; 8];
        // Dummy value and bits above each entry's length are dropped.
        m.pack(&[1, 0x7, 0xFABC, 0x80_0001, 1], &mut out);
        // bit0 = 1; bits 4..15 = 0xABC; bits 16..39 = 0x800001; bit 40 = 1.
        assert_eq!(out[..6], [0xC1, 0xAB, 0x01, 0x00, 0x80, 0x01]);
        let v = m.unpack_values(&out).unwrap();
        assert_eq!(v.as_slice(), &[1, 0, 0xABC, 0x80_0001, 1]);
        assert_eq!(sign_extend(v.values[3], 24), -0x7F_FFFF);
    }

    #[test]
    fn short_frame_is_a_typed_error() {
        let m = Mapping::from_raw(&[0x6040_0010, 0x607A_0020]).unwrap();
        let mut vals = [7u64; 2];
        assert_eq!(
            m.unpack(&[1, 2, 3, 4, 5], &mut vals),
            Err(PdoError::TooShort {
                expected_bits: 48,
                got_bytes: 5
            })
        );
        assert_eq!(vals, [7, 7]);
        // Longer frames are accepted.
        assert!(m.unpack(&[0; 8], &mut vals).is_ok());
    }

    fn od() -> ObjectDictionary<'static, 8, 32> {
        let mut od = ObjectDictionary::new();
        od.insert_all(&[
            EntryDef::new(
                Address::new(0x6040, 0),
                "cw",
                DataType::Unsigned16,
                AccessType::Rww,
            )
            .mappable(),
            EntryDef::new(
                Address::new(0x6041, 0),
                "sw",
                DataType::Unsigned16,
                AccessType::Ro,
            )
            .mappable(),
            EntryDef::new(
                Address::new(0x607A, 0),
                "target",
                DataType::Integer32,
                AccessType::Rww,
            )
            .mappable(),
            EntryDef::new(
                Address::new(0x2001, 0),
                "i24",
                DataType::Integer24,
                AccessType::Rw,
            )
            .mappable(),
            EntryDef::new(
                Address::new(0x6060, 0),
                "mode",
                DataType::Integer8,
                AccessType::Rw,
            ),
        ])
        .unwrap();
        od
    }

    #[test]
    fn validates_against_the_dictionary() {
        let od = od();
        let rx = Mapping::from_raw(&[0x6040_0010, 0x607A_0020, 0x0005_0008]).unwrap();
        assert_eq!(rx.validate(&od, false), Ok(()));
        let sw_in_rpdo = Mapping::from_raw(&[0x6041_0010]).unwrap();
        assert_eq!(
            sw_in_rpdo.validate(&od, false).unwrap_err().abort_code(),
            AbortCode::NotMappable
        );
        assert_eq!(sw_in_rpdo.validate(&od, true), Ok(()));
        let missing = Mapping::from_raw(&[0x6041_0010, 0x6064_0020]).unwrap();
        assert_eq!(
            missing.validate(&od, true),
            Err(MappingError::Object {
                position: 2,
                addr: Address::new(0x6064, 0),
                code: AbortCode::NoObject
            })
        );
        let not_mappable = Mapping::from_raw(&[0x6060_0008]).unwrap();
        assert_eq!(
            not_mappable.validate(&od, false).unwrap_err().abort_code(),
            AbortCode::NotMappable
        );
        let too_long = Mapping::from_raw(&[0x6040_0020]).unwrap();
        assert_eq!(
            too_long.validate(&od, false).unwrap_err().abort_code(),
            AbortCode::NotMappable
        );
    }

    #[test]
    fn od_round_trip_sign_extends() {
        let mut od = od();
        let m = Mapping::from_raw(&[0x6040_0010, 0x2001_0018]).unwrap();
        let data = [0x0F, 0x00, 0xFF, 0xFF, 0xFF];
        let v = m.unpack_values(&data).unwrap();
        m.store_into_od(v.as_slice(), &mut od).unwrap();
        assert_eq!(od.get_u16(Address::new(0x6040, 0)), Ok(0x000F));
        assert_eq!(od.get_i32(Address::new(0x2001, 0)), Ok(-1));
        let mut out = [0u8; 8];
        let n = m.pack_from_od(&od, &mut out).unwrap();
        assert_eq!(&out[..n], &data);
    }

    #[test]
    fn kept_positions_are_found_once_and_survive_a_moved_dictionary() {
        let mut od = od();
        let m = Mapping::from_raw(&[0x6040_0010, 0x2001_0018]).unwrap();
        let mut at: Positions = [u16::MAX; MAX_ENTRIES];
        m.store_into_od_at(&[0x0F, 0xFF_FFFF], &mut od, &mut at)
            .unwrap();
        // The positions were found and kept, the dummy-free entries only.
        assert!(at[..2].iter().all(|&p| p != u16::MAX));
        assert!(at[2..].iter().all(|&p| p == u16::MAX));
        // Kept positions pointing at the wrong entries (as after an insert) are only tried.
        let mut swapped = at;
        swapped.swap(0, 1);
        let mut out = [0u8; 8];
        let n = m.pack_from_od_at(&od, &mut out, &mut swapped).unwrap();
        assert_eq!(&out[..n], &[0x0F, 0x00, 0xFF, 0xFF, 0xFF]);
        assert_eq!(swapped, at, "found again and kept");
        m.store_into_od_at(&[0x06, 0x01], &mut od, &mut at).unwrap();
        assert_eq!(od.get_u16(Address::new(0x6040, 0)), Ok(6));
        assert_eq!(od.get_i32(Address::new(0x2001, 0)), Ok(1));
    }

    fn mapping_and_values() -> impl Strategy<Value = (Vec<u8>, Vec<u64>)> {
        // Between 1 and 8 lengths of 1..=64 bits whose sum stays <= 64.
        prop::collection::vec(1u8..=64, 1..=8)
            .prop_map(|mut lens| {
                let mut total = 0u32;
                lens.retain(|&b| {
                    total += b as u32;
                    total <= 64
                });
                if lens.is_empty() {
                    lens.push(1);
                }
                lens
            })
            .prop_flat_map(|lens| {
                let n = lens.len();
                (Just(lens), prop::collection::vec(any::<u64>(), n))
            })
    }

    proptest! {
        #[test]
        fn pack_then_unpack_is_identity((lens, values) in mapping_and_values()) {
            let entries: Vec<MappingEntry> = lens
                .iter()
                .enumerate()
                .map(|(i, &b)| MappingEntry::new(0x2000, i as u8 + 1, b))
                .collect();
            let m = Mapping::new(&entries).unwrap();
            let mut out = [0u8; 8];
            let n = m.pack(&values, &mut out);
            prop_assert_eq!(n, m.byte_len());
            let back = m.unpack_values(&out[..n]).unwrap();
            for (i, (&b, &v)) in lens.iter().zip(&values).enumerate() {
                prop_assert_eq!(back.values[i], v & mask(b));
            }
            // And the other way: the frame bytes survive unpack then pack.
            let mut again = [0u8; 8];
            m.pack(back.as_slice(), &mut again);
            prop_assert_eq!(again, out);
        }
    }
}
