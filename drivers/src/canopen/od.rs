//! The object dictionary as the SDO server and the PDO engine see it.
//!
//! [`ObjectAccess`] is the boundary between protocol code and storage: the SDO server reads and
//! writes through it, so a device's dictionary can veto a write with the abort code its manual
//! names (a value out of range, a write in the wrong state).

use super::{AbortCode, Address};
use crate::hash_index::HashIndex;

/// Read and write access to an object dictionary, by address.
pub trait ObjectAccess {
    /// The size in bytes of the object's current value (for an SDO upload's size indication).
    fn size(&self, addr: Address) -> Result<usize, AbortCode>;

    /// Copies up to `buf.len()` bytes of the value, starting at byte `offset`, into `buf`.
    /// Returns how many bytes were copied; segmented and block uploads read in pieces.
    fn read(&mut self, addr: Address, offset: usize, buf: &mut [u8]) -> Result<usize, AbortCode>;

    /// Writes a whole value. The dictionary checks access, length and range, and answers with
    /// the abort code that explains a refusal.
    fn write(&mut self, addr: Address, data: &[u8]) -> Result<(), AbortCode>;
}

/// A CiA 301 basic data type, by its object-dictionary index (0001h..001Bh).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
#[repr(u16)]
pub enum DataType {
    /// BOOLEAN (0001h): one byte on SDO, one bit when mapped as a 1-bit PDO entry.
    Boolean = 0x0001,
    /// INTEGER8 (0002h).
    Integer8 = 0x0002,
    /// INTEGER16 (0003h).
    Integer16 = 0x0003,
    /// INTEGER32 (0004h).
    Integer32 = 0x0004,
    /// UNSIGNED8 (0005h).
    Unsigned8 = 0x0005,
    /// UNSIGNED16 (0006h).
    Unsigned16 = 0x0006,
    /// UNSIGNED32 (0007h).
    Unsigned32 = 0x0007,
    /// REAL32 (0008h), IEEE 754 single precision.
    Real32 = 0x0008,
    /// VISIBLE_STRING (0009h).
    VisibleString = 0x0009,
    /// OCTET_STRING (000Ah).
    OctetString = 0x000A,
    /// UNICODE_STRING (000Bh).
    UnicodeString = 0x000B,
    /// TIME_OF_DAY (000Ch), 6 bytes.
    TimeOfDay = 0x000C,
    /// TIME_DIFFERENCE (000Dh), 6 bytes.
    TimeDifference = 0x000D,
    /// DOMAIN (000Fh): an opaque block of bytes.
    Domain = 0x000F,
    /// INTEGER24 (0010h).
    Integer24 = 0x0010,
    /// REAL64 (0011h).
    Real64 = 0x0011,
    /// INTEGER40 (0012h).
    Integer40 = 0x0012,
    /// INTEGER48 (0013h).
    Integer48 = 0x0013,
    /// INTEGER56 (0014h).
    Integer56 = 0x0014,
    /// INTEGER64 (0015h).
    Integer64 = 0x0015,
    /// UNSIGNED24 (0016h).
    Unsigned24 = 0x0016,
    /// UNSIGNED40 (0018h).
    Unsigned40 = 0x0018,
    /// UNSIGNED48 (0019h).
    Unsigned48 = 0x0019,
    /// UNSIGNED56 (001Ah).
    Unsigned56 = 0x001A,
    /// UNSIGNED64 (001Bh).
    Unsigned64 = 0x001B,
}

/// How a data type's bytes are interpreted (for limits and typed access).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum TypeClass {
    /// BOOLEAN and UNSIGNEDn: zero-extended little-endian.
    Unsigned,
    /// INTEGERn: two's complement, sign-extended.
    Signed,
    /// REAL32 / REAL64.
    Real,
    /// Strings, DOMAIN, TIME_OF_DAY, TIME_DIFFERENCE: bytes without arithmetic.
    Bytes,
}

impl DataType {
    /// The type for a CiA 301 data type index, `None` for codes this stack does not model.
    pub const fn from_code(code: u16) -> Option<DataType> {
        use DataType::*;
        Some(match code {
            0x0001 => Boolean,
            0x0002 => Integer8,
            0x0003 => Integer16,
            0x0004 => Integer32,
            0x0005 => Unsigned8,
            0x0006 => Unsigned16,
            0x0007 => Unsigned32,
            0x0008 => Real32,
            0x0009 => VisibleString,
            0x000A => OctetString,
            0x000B => UnicodeString,
            0x000C => TimeOfDay,
            0x000D => TimeDifference,
            0x000F => Domain,
            0x0010 => Integer24,
            0x0011 => Real64,
            0x0012 => Integer40,
            0x0013 => Integer48,
            0x0014 => Integer56,
            0x0015 => Integer64,
            0x0016 => Unsigned24,
            0x0018 => Unsigned40,
            0x0019 => Unsigned48,
            0x001A => Unsigned56,
            0x001B => Unsigned64,
            _ => return None,
        })
    }

    /// The data type index.
    pub const fn code(self) -> u16 {
        self as u16
    }

    /// The fixed size in bytes, `None` for the variable-length types (strings, DOMAIN).
    pub const fn size(self) -> Option<usize> {
        use DataType::*;
        Some(match self {
            Boolean | Integer8 | Unsigned8 => 1,
            Integer16 | Unsigned16 => 2,
            Integer24 | Unsigned24 => 3,
            Integer32 | Unsigned32 | Real32 => 4,
            Integer40 | Unsigned40 => 5,
            Integer48 | Unsigned48 | TimeOfDay | TimeDifference => 6,
            Integer56 | Unsigned56 => 7,
            Integer64 | Unsigned64 | Real64 => 8,
            VisibleString | OctetString | UnicodeString | Domain => return None,
        })
    }

    /// How the bytes are interpreted.
    pub const fn class(self) -> TypeClass {
        use DataType::*;
        match self {
            Boolean | Unsigned8 | Unsigned16 | Unsigned24 | Unsigned32 | Unsigned40
            | Unsigned48 | Unsigned56 | Unsigned64 => TypeClass::Unsigned,
            Integer8 | Integer16 | Integer24 | Integer32 | Integer40 | Integer48 | Integer56
            | Integer64 => TypeClass::Signed,
            Real32 | Real64 => TypeClass::Real,
            VisibleString | OctetString | UnicodeString | Domain | TimeOfDay | TimeDifference => {
                TypeClass::Bytes
            }
        }
    }

    /// Whether `index` is one a PDO mapping may name as a dummy entry: the data type indices
    /// 0001h..0007h (BOOLEAN to UNSIGNED32) stand for "this many bits, no object".
    pub const fn is_dummy_index(index: u16) -> bool {
        index >= 0x0001 && index <= 0x0007
    }
}

/// The access type of an entry (CiA 306 `AccessType`). `rwr` and `rww` are read-write entries
/// whose PDO direction is fixed: `rwr` maps into TPDOs (the device produces it), `rww` into
/// RPDOs (the device consumes it).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum AccessType {
    /// Read only; the device may change the value.
    Ro,
    /// Write only.
    Wo,
    /// Read-write.
    Rw,
    /// Read-write, mappable to TPDOs only.
    Rwr,
    /// Read-write, mappable to RPDOs only.
    Rww,
    /// Read only and never changes.
    Const,
}

impl AccessType {
    /// Whether an SDO upload may read it.
    pub const fn readable(self) -> bool {
        !matches!(self, AccessType::Wo)
    }
    /// Whether an SDO download may write it.
    pub const fn writable(self) -> bool {
        matches!(
            self,
            AccessType::Wo | AccessType::Rw | AccessType::Rwr | AccessType::Rww
        )
    }
    /// Whether a TPDO may carry it (the device reads it to transmit).
    pub const fn tpdo_direction(self) -> bool {
        !matches!(self, AccessType::Wo | AccessType::Rww)
    }
    /// Whether an RPDO may carry it (the device writes it on reception).
    pub const fn rpdo_direction(self) -> bool {
        matches!(self, AccessType::Wo | AccessType::Rw | AccessType::Rww)
    }
}

/// A value as written in a definition (default, limits) or read by device code.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Value<'a> {
    /// An unsigned integer (also BOOLEAN: 0 or 1).
    Unsigned(u64),
    /// A signed integer.
    Signed(i64),
    /// A REAL32.
    Real32(f32),
    /// A REAL64.
    Real64(f64),
    /// Raw bytes (strings, DOMAIN, TIME_OF_DAY).
    Bytes(&'a [u8]),
}

/// Why a definition could not become an entry of an [`ObjectDictionary`].
#[derive(Debug, Clone, Copy, PartialEq, Eq, thiserror::Error)]
pub enum OdError {
    /// All `N` entry slots are used.
    #[error("object dictionary full: {capacity} entries, cannot add {addr}")]
    Full {
        /// The entry capacity `N`.
        capacity: usize,
        /// The entry that did not fit.
        addr: Address,
    },
    /// The byte arena cannot hold the value.
    #[error("object dictionary arena full: {addr} needs {needed} bytes, {available} left")]
    ArenaFull {
        /// The entry that did not fit.
        addr: Address,
        /// Bytes it needs.
        needed: usize,
        /// Bytes still free.
        available: usize,
    },
    /// The address is already defined.
    #[error("{0} is defined twice")]
    Duplicate(Address),
    /// The default value does not fit the type (or is of another kind).
    #[error("the default of {addr} does not fit its type: {code}")]
    BadDefault {
        /// The entry.
        addr: Address,
        /// The abort code a write of that value would get.
        code: AbortCode,
    },
}

/// The definition of one object dictionary entry (one sub-index).
///
/// `const`-constructible, so a device's dictionary can be a table of `static` definitions:
///
/// ```
/// use drivers::canopen::Address;
/// use drivers::canopen::od::{AccessType, DataType, EntryDef, Value};
/// const TARGET: EntryDef<'static> =
///     EntryDef::new(Address::new(0x607A, 0), "target position", DataType::Integer32, AccessType::Rww)
///         .mappable()
///         .limits(Value::Signed(-1_000_000), Value::Signed(1_000_000));
/// assert!(TARGET.pdo_mappable);
/// ```
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct EntryDef<'a> {
    /// Index and sub-index.
    pub addr: Address,
    /// The parameter name (for diagnostics).
    pub name: &'a str,
    /// The data type.
    pub data_type: DataType,
    /// The access type.
    pub access: AccessType,
    /// Whether a PDO may map it.
    pub pdo_mappable: bool,
    /// The value after reset.
    pub default: Value<'a>,
    /// The lowest value a write may set (inclusive).
    pub low: Option<Value<'a>>,
    /// The highest value a write may set (inclusive).
    pub high: Option<Value<'a>>,
    /// Bytes reserved for variable-length types (strings, DOMAIN); ignored for fixed sizes.
    pub capacity: usize,
}

impl<'a> EntryDef<'a> {
    /// A non-mappable entry with default zero (empty for variable-length types) and no limits.
    pub const fn new(
        addr: Address,
        name: &'a str,
        data_type: DataType,
        access: AccessType,
    ) -> Self {
        let default = match data_type {
            DataType::Real32 => Value::Real32(0.0),
            DataType::Real64 => Value::Real64(0.0),
            _ if matches!(data_type.class(), TypeClass::Bytes) => Value::Bytes(&[]),
            _ => Value::Unsigned(0),
        };
        EntryDef {
            addr,
            name,
            data_type,
            access,
            pdo_mappable: false,
            default,
            low: None,
            high: None,
            capacity: 0,
        }
    }
    /// The same entry, PDO-mappable.
    pub const fn mappable(mut self) -> Self {
        self.pdo_mappable = true;
        self
    }
    /// The same entry with a default value.
    pub const fn default_value(mut self, v: Value<'a>) -> Self {
        self.default = v;
        self
    }
    /// The same entry with inclusive limits.
    pub const fn limits(mut self, low: Value<'a>, high: Value<'a>) -> Self {
        self.low = Some(low);
        self.high = Some(high);
        self
    }
    /// The same entry with `n` bytes reserved (strings, DOMAIN).
    pub const fn capacity(mut self, n: usize) -> Self {
        self.capacity = n;
        self
    }
    /// Bytes this entry occupies in the arena.
    pub const fn storage_size(&self) -> usize {
        match self.data_type.size() {
            Some(s) => s,
            None => self.capacity,
        }
    }
}

/// Encodes `v` as the little-endian bytes of `dt` into `out`; returns the length.
///
/// Integers must fit the type's width (a `Signed` value fits an unsigned type only if it is not
/// negative, and vice versa). The error is the abort code an SDO write of that value would get.
pub fn encode_value(dt: DataType, v: &Value<'_>, out: &mut [u8]) -> Result<usize, AbortCode> {
    match (dt.class(), v) {
        (TypeClass::Bytes, Value::Bytes(b)) => {
            let dst = out.get_mut(..b.len()).ok_or(AbortCode::TooLong)?;
            dst.copy_from_slice(b);
            Ok(b.len())
        }
        (TypeClass::Real, Value::Real32(f)) if dt == DataType::Real32 => put(out, &f.to_le_bytes()),
        (TypeClass::Real, Value::Real64(f)) if dt == DataType::Real64 => put(out, &f.to_le_bytes()),
        (TypeClass::Real, Value::Real32(f)) => put(out, &(*f as f64).to_le_bytes()),
        (TypeClass::Unsigned | TypeClass::Signed, Value::Unsigned(_) | Value::Signed(_)) => {
            let size = dt.size().unwrap_or(8);
            let raw = int_to_raw(dt, v)?;
            put(out, raw.to_le_bytes().get(..size).unwrap_or(&[]))
        }
        _ => Err(AbortCode::TypeMismatch),
    }
}

fn put(out: &mut [u8], bytes: &[u8]) -> Result<usize, AbortCode> {
    let dst = out.get_mut(..bytes.len()).ok_or(AbortCode::TooLong)?;
    dst.copy_from_slice(bytes);
    Ok(bytes.len())
}

/// The bits of an integer type (BOOLEAN counts as 1 for range purposes).
fn int_bits(dt: DataType) -> u32 {
    if dt == DataType::Boolean {
        1
    } else {
        dt.size().unwrap_or(8) as u32 * 8
    }
}

/// The search key of an address: sorts as `Address` does.
const fn key(a: Address) -> u32 {
    (a.index as u32) << 8 | a.sub as u32
}

/// The two's-complement raw form of an integer value, checked against the type's range.
fn int_to_raw(dt: DataType, v: &Value<'_>) -> Result<u64, AbortCode> {
    let bits = int_bits(dt);
    match (dt.class(), *v) {
        (TypeClass::Unsigned, Value::Unsigned(u)) => {
            if bits < 64 && u >> bits != 0 {
                Err(AbortCode::ValueTooHigh)
            } else {
                Ok(u)
            }
        }
        (TypeClass::Unsigned, Value::Signed(i)) => {
            if i < 0 {
                Err(AbortCode::ValueTooLow)
            } else {
                int_to_raw(dt, &Value::Unsigned(i as u64))
            }
        }
        (TypeClass::Signed, Value::Signed(i)) => {
            let (min, max) = signed_range(bits);
            if i < min {
                Err(AbortCode::ValueTooLow)
            } else if i > max {
                Err(AbortCode::ValueTooHigh)
            } else {
                Ok(i as u64)
            }
        }
        (TypeClass::Signed, Value::Unsigned(u)) => {
            if u > signed_range(bits).1 as u64 {
                Err(AbortCode::ValueTooHigh)
            } else {
                Ok(u)
            }
        }
        _ => Err(AbortCode::TypeMismatch),
    }
}

const fn signed_range(bits: u32) -> (i64, i64) {
    if bits >= 64 {
        (i64::MIN, i64::MAX)
    } else {
        (-(1i64 << (bits - 1)), (1i64 << (bits - 1)) - 1)
    }
}

/// Decodes the little-endian bytes of `dt` into a [`Value`] (integers sign- or zero-extended).
pub fn decode_value(dt: DataType, bytes: &[u8]) -> Value<'_> {
    match dt.class() {
        TypeClass::Bytes => Value::Bytes(bytes),
        TypeClass::Real => {
            if dt == DataType::Real32 {
                let mut b = [0u8; 4];
                let n = bytes.len().min(4);
                b[..n].copy_from_slice(&bytes[..n]);
                Value::Real32(f32::from_le_bytes(b))
            } else {
                let mut b = [0u8; 8];
                let n = bytes.len().min(8);
                b[..n].copy_from_slice(&bytes[..n]);
                Value::Real64(f64::from_le_bytes(b))
            }
        }
        TypeClass::Unsigned => Value::Unsigned(le_u64(bytes)),
        TypeClass::Signed => {
            let n = bytes.len().min(8);
            let raw = le_u64(bytes);
            let shift = 64 - 8 * n as u32;
            if n == 0 {
                Value::Signed(0)
            } else {
                Value::Signed(((raw << shift) as i64) >> shift)
            }
        }
    }
}

/// Up to 8 little-endian bytes as a zero-extended `u64`.
pub fn le_u64(bytes: &[u8]) -> u64 {
    // The widths device code reads every cycle, without a call to memcpy.
    match *bytes {
        [a] => return u64::from(a),
        [a, b] => return u64::from(u16::from_le_bytes([a, b])),
        [a, b, c, d] => return u64::from(u32::from_le_bytes([a, b, c, d])),
        [a, b, c, d, e, f, g, h] => return u64::from_le_bytes([a, b, c, d, e, f, g, h]),
        _ => {}
    }
    let mut b = [0u8; 8];
    let n = bytes.len().min(8);
    b[..n].copy_from_slice(&bytes[..n]);
    u64::from_le_bytes(b)
}

/// `a < b` for values of one type; `None` when they cannot be compared (bytes, mixed reals).
fn less(a: &Value<'_>, b: &Value<'_>) -> Option<bool> {
    use Value::*;
    Some(match (*a, *b) {
        (Unsigned(x), Unsigned(y)) => x < y,
        (Signed(x), Signed(y)) => x < y,
        (Unsigned(x), Signed(y)) => (x as i128) < y as i128,
        (Signed(x), Unsigned(y)) => (x as i128) < y as i128,
        (Real32(x), Real32(y)) => x < y,
        (Real64(x), Real64(y)) => x < y,
        (Real32(x), Real64(y)) => (x as f64) < y,
        (Real64(x), Real32(y)) => x < y as f64,
        _ => return None,
    })
}

/// Checks a value against a definition's limits.
fn check_limits(def: &EntryDef<'_>, v: &Value<'_>) -> Result<(), AbortCode> {
    if let Some(low) = &def.low
        && less(v, low) == Some(true)
    {
        return Err(AbortCode::ValueTooLow);
    }
    if let Some(high) = &def.high
        && less(high, v) == Some(true)
    {
        return Err(AbortCode::ValueTooHigh);
    }
    Ok(())
}

/// An object's address with the position it had in a dictionary when it was looked up
/// ([`ObjectDictionary::resolve`]). Device code that reads and writes the same objects every
/// cycle keeps these: an access through one checks the position with one compare instead of
/// searching. A position that no longer holds the address (an insert moved the entries, or the
/// handle came from another dictionary) falls back to the search, so a stale handle is slower,
/// never wrong.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Resolved {
    addr: Address,
    pos: u16,
}

impl Resolved {
    /// The object's address.
    pub const fn address(self) -> Address {
        self.addr
    }
}

/// Where an access finds its entry: an [`Address`] (searched) or a [`Resolved`] handle.
pub trait Locate: Copy {
    /// The address of the entry.
    fn address(self) -> Address;
    /// The position to try first.
    fn hint(self) -> Option<usize>;
}

impl Locate for Address {
    #[inline]
    fn address(self) -> Address {
        self
    }
    #[inline]
    fn hint(self) -> Option<usize> {
        None
    }
}

impl Locate for Resolved {
    #[inline]
    fn address(self) -> Address {
        self.addr
    }
    #[inline]
    fn hint(self) -> Option<usize> {
        Some(usize::from(self.pos))
    }
}

/// What a value access needs of an entry, kept apart from its definition: a compact array
/// that the per-cycle reads and writes of device code touch, instead of the definitions.
#[derive(Debug, Clone, Copy)]
struct Slot {
    offset: usize,
    len: usize,
    data_type: DataType,
    /// `data_type.class()` and its integer bits ([`int_bits`]), for the typed accesses.
    class: TypeClass,
    bits: u8,
    /// Limits or a BOOLEAN: a write must check the value, not only its length.
    checked: bool,
}

/// A static, allocation-free object dictionary: up to `N` entries (sub-indices), their values in
/// one `BYTES`-byte arena.
///
/// Entries stay sorted by address, so a lookup is a binary search. Values are stored as their
/// little-endian wire bytes, so an SDO upload or a PDO is a copy.
///
/// Two ways in:
/// - [`ObjectAccess`] (the SDO server's view) enforces access, length and limits.
/// - Device code uses the typed getters and setters (`get_u32`, `set_i32`, ...) and
///   [`ObjectDictionary::set_raw`], which skip the access check (a device updates its own
///   read-only statusword) but still check type, length and limits.
///
/// # Vetoing writes
///
/// A device that must refuse some writes with its own abort code (a write in the wrong state,
/// a value its hardware cannot take) wraps the dictionary and implements [`ObjectAccess`] itself,
/// calling [`ObjectDictionary::write_with`]: the closure runs after the dictionary's own checks
/// and before the value is stored, so a refused write changes nothing.
///
/// ```
/// use drivers::canopen::{AbortCode, Address};
/// use drivers::canopen::od::{AccessType, DataType, EntryDef, ObjectAccess, ObjectDictionary};
///
/// const MODE: Address = Address::new(0x6060, 0);
/// struct Drive {
///     od: ObjectDictionary<'static, 4, 16>,
///     moving: bool,
/// }
/// impl ObjectAccess for Drive {
///     fn size(&self, a: Address) -> Result<usize, AbortCode> { self.od.size(a) }
///     fn read(&mut self, a: Address, off: usize, buf: &mut [u8]) -> Result<usize, AbortCode> {
///         self.od.read(a, off, buf)
///     }
///     fn write(&mut self, a: Address, data: &[u8]) -> Result<(), AbortCode> {
///         let moving = self.moving;
///         self.od.write_with(a, data, |def, _new| {
///             // The mode may change only at standstill.
///             if def.addr == MODE && moving { Err(AbortCode::DeviceState) } else { Ok(()) }
///         })
///     }
/// }
///
/// let mut d = Drive { od: ObjectDictionary::new(), moving: true };
/// d.od.insert(EntryDef::new(MODE, "modes of operation", DataType::Integer8, AccessType::Rw)).unwrap();
/// assert_eq!(d.write(MODE, &[1]), Err(AbortCode::DeviceState));
/// d.moving = false;
/// assert_eq!(d.write(MODE, &[1]), Ok(()));
/// assert_eq!(d.od.get_i8(MODE), Ok(1));
/// ```
#[derive(Debug, Clone)]
pub struct ObjectDictionary<'a, const N: usize, const BYTES: usize> {
    slots: heapless::Vec<Slot, N>,
    /// The definitions, in the same order as `slots`.
    defs: heapless::Vec<EntryDef<'a>, N>,
    /// `index << 8 | sub` of each slot, in the same order: a compact array to search.
    keys: heapless::Vec<u32, N>,
    /// A hash index over `keys` ([`HashIndex`]): a key it does not hold is found by a binary
    /// search.
    /// Device code reads and writes dozens of values a cycle by address; a probe or two is
    /// cheaper than a binary search over hundreds of keys.
    index: HashIndex<N>,
    /// Bumped by every change of a stored value.
    generation: u32,
    arena: [u8; BYTES],
    used: usize,
}

impl<const N: usize, const BYTES: usize> Default for ObjectDictionary<'_, N, BYTES> {
    fn default() -> Self {
        Self::new()
    }
}

impl<'a, const N: usize, const BYTES: usize> ObjectDictionary<'a, N, BYTES> {
    /// An empty dictionary.
    pub const fn new() -> Self {
        ObjectDictionary {
            slots: heapless::Vec::new(),
            defs: heapless::Vec::new(),
            keys: heapless::Vec::new(),
            index: HashIndex::new(),
            generation: 0,
            arena: [0; BYTES],
            used: 0,
        }
    }

    /// Adds an entry with its default value.
    pub fn insert(&mut self, def: EntryDef<'a>) -> Result<(), OdError> {
        let pos = match self.keys.binary_search(&key(def.addr)) {
            Ok(_) => return Err(OdError::Duplicate(def.addr)),
            Err(p) => p,
        };
        if self.slots.is_full() {
            return Err(OdError::Full {
                capacity: N,
                addr: def.addr,
            });
        }
        let size = def.storage_size();
        let available = BYTES - self.used;
        if size > available {
            return Err(OdError::ArenaFull {
                addr: def.addr,
                needed: size,
                available,
            });
        }
        let offset = self.used;
        let region = &mut self.arena[offset..offset + size];
        let len = encode_value(def.data_type, &def.default, region).map_err(|code| {
            OdError::BadDefault {
                addr: def.addr,
                code,
            }
        })?;
        let checked = def.low.is_some() || def.high.is_some() || def.data_type == DataType::Boolean;
        let slot = Slot {
            offset,
            len,
            data_type: def.data_type,
            class: def.data_type.class(),
            bits: int_bits(def.data_type) as u8,
            checked,
        };
        // Capacity checked above, so the insert cannot fail.
        self.slots.insert(pos, slot).map_err(|_| OdError::Full {
            capacity: N,
            addr: def.addr,
        })?;
        // Same capacity as `slots`, which just took the entry.
        let _ = self.keys.insert(pos, key(def.addr));
        let _ = self.defs.insert(pos, def);
        self.reindex();
        self.used += size;
        Ok(())
    }

    /// Adds every definition of a table.
    pub fn insert_all(&mut self, defs: &[EntryDef<'a>]) -> Result<(), OdError> {
        defs.iter().try_for_each(|d| self.insert(*d))
    }

    /// Restores every entry's default value.
    pub fn reset_to_defaults(&mut self) {
        self.reset_range(0x0000, 0xFFFF);
    }

    /// Restores the default values of the entries with `first <= index <= last` (a reset
    /// communication reloads 1000h..1FFFh only).
    pub fn reset_range(&mut self, first: u16, last: u16) {
        self.generation = self.generation.wrapping_add(1);
        for (s, def) in self.slots.iter_mut().zip(self.defs.iter()) {
            if def.addr.index < first || def.addr.index > last {
                continue;
            }
            let cap = def.storage_size();
            let region = &mut self.arena[s.offset..s.offset + cap];
            // Defaults were checked at insert.
            s.len = encode_value(def.data_type, &def.default, region).unwrap_or(s.len);
        }
    }

    /// How many entries are defined.
    pub fn len(&self) -> usize {
        self.slots.len()
    }

    /// Whether no entry is defined.
    pub fn is_empty(&self) -> bool {
        self.slots.is_empty()
    }

    /// Arena bytes in use.
    pub fn bytes_used(&self) -> usize {
        self.used
    }

    /// Every definition, in address order.
    pub fn entries(&self) -> impl Iterator<Item = &EntryDef<'a>> {
        self.defs.iter()
    }

    /// Rebuilds the hash index (an insert moves the positions after it).
    fn reindex(&mut self) {
        self.index.rebuild(self.keys.iter().copied());
    }

    fn find(&self, addr: Address) -> Result<usize, AbortCode> {
        match self.index.search(key(addr), &self.keys, |&k| k) {
            Ok(i) => Ok(i),
            Err(p) => {
                // A neighbour with the same index means the object exists but not the sub.
                let same_index =
                    |i: usize| self.defs.get(i).is_some_and(|d| d.addr.index == addr.index);
                if same_index(p) || (p > 0 && same_index(p - 1)) {
                    Err(AbortCode::NoSubIndex)
                } else {
                    Err(AbortCode::NoObject)
                }
            }
        }
    }

    /// The position of `at`'s entry: its hint if that still holds the address, else found by
    /// the search.
    #[inline]
    fn locate(&self, at: impl Locate) -> Result<usize, AbortCode> {
        let addr = at.address();
        if let Some(p) = at.hint()
            && self.keys.get(p) == Some(&key(addr))
        {
            return Ok(p);
        }
        self.find(addr)
    }

    /// The position of `addr`'s entry, trying `hint` first and keeping the position found in
    /// it (a PDO engine's positions of its mapped objects).
    #[inline]
    pub(crate) fn locate_hinted(&self, addr: Address, hint: &mut u16) -> Result<usize, AbortCode> {
        let p = usize::from(*hint);
        if self.keys.get(p) == Some(&key(addr)) {
            return Ok(p);
        }
        let p = self.find(addr)?;
        *hint = u16::try_from(p).unwrap_or(u16::MAX);
        Ok(p)
    }

    /// `addr` with the position of its entry now, for later accesses through the handle. An
    /// address without an entry gives a handle that every access searches for (and refuses as
    /// the address would be refused).
    pub fn resolve(&self, addr: Address) -> Resolved {
        let mut pos = u16::MAX;
        let _ = self.locate_hinted(addr, &mut pos);
        Resolved { addr, pos }
    }

    /// [`ObjectDictionary::set_int`] at a position from [`ObjectDictionary::locate_hinted`].
    pub(crate) fn set_int_at(&mut self, i: usize, v: i64) -> Result<(), AbortCode> {
        match self.slots.get(i).map(|s| s.class) {
            Some(TypeClass::Signed | TypeClass::Unsigned) => self.store_int(i, Value::Signed(v)),
            Some(_) => Err(AbortCode::TypeMismatch),
            None => Err(AbortCode::NoObject),
        }
    }

    /// The definition at a position from [`ObjectDictionary::locate_hinted`].
    pub(crate) fn entry_at(&self, i: usize) -> &EntryDef<'a> {
        &self.defs[i]
    }

    /// [`ObjectDictionary::set_raw`] at a position from [`ObjectDictionary::locate_hinted`].
    pub(crate) fn set_raw_at(&mut self, i: usize, data: &[u8]) -> Result<(), AbortCode> {
        self.check_write(i, data)?;
        self.store(i, data);
        Ok(())
    }

    /// The definition of an entry: `NoObject` or `NoSubIndex` if it does not exist.
    pub fn entry(&self, at: impl Locate) -> Result<&EntryDef<'a>, AbortCode> {
        self.locate(at).map(|i| &self.defs[i])
    }

    /// The current value bytes of the entry at a position from
    /// [`ObjectDictionary::locate_hinted`].
    pub(crate) fn raw_at(&self, i: usize) -> &[u8] {
        let s = &self.slots[i];
        &self.arena[s.offset..s.offset + s.len]
    }

    /// The current value bytes, without the access check (device code, PDO transmission).
    pub fn raw(&self, at: impl Locate) -> Result<&[u8], AbortCode> {
        Ok(self.raw_at(self.locate(at)?))
    }

    /// The current value, decoded.
    pub fn value(&self, at: impl Locate) -> Result<Value<'_>, AbortCode> {
        let i = self.locate(at)?;
        Ok(decode_value(self.slots[i].data_type, self.raw_at(i)))
    }

    /// Checks a write of `data` to the entry at slot `i` (length, range, limits); access is the
    /// caller's business.
    fn check_write(&self, i: usize, data: &[u8]) -> Result<(), AbortCode> {
        let def = &self.defs[i];
        match def.data_type.size() {
            Some(size) if data.len() > size => return Err(AbortCode::TooLong),
            Some(size) if data.len() < size => return Err(AbortCode::TooShort),
            None if data.len() > def.capacity => return Err(AbortCode::TooLong),
            _ => {}
        }
        if !self.slots[i].checked {
            return Ok(());
        }
        let v = decode_value(def.data_type, data);
        if def.data_type == DataType::Boolean && v != Value::Unsigned(0) && v != Value::Unsigned(1)
        {
            return Err(AbortCode::InvalidValue);
        }
        check_limits(def, &v)
    }

    fn store(&mut self, i: usize, data: &[u8]) {
        let s = &mut self.slots[i];
        let dst = &mut self.arena[s.offset..s.offset + data.len()];
        let mut changed = s.len != data.len();
        if data.len() <= 8 {
            // Values written every cycle are a few bytes: compare and copy in one pass
            // rather than calling memcmp and memcpy.
            for (d, &b) in dst.iter_mut().zip(data) {
                changed |= *d != b;
                *d = b;
            }
        } else if changed || *dst != *data {
            dst.copy_from_slice(data);
            changed = true;
        }
        if changed {
            s.len = data.len();
            self.generation = self.generation.wrapping_add(1);
        }
    }

    /// A counter that changes whenever a stored value changes: a reader that packs values
    /// (TPDOs) can skip the work while it is unchanged.
    pub fn generation(&self) -> u32 {
        self.generation
    }

    /// A write as [`ObjectAccess::write`] does it, with `veto` asked last, before the value is
    /// stored. `veto` sees the definition and the new bytes and may refuse with any code.
    pub fn write_with(
        &mut self,
        addr: Address,
        data: &[u8],
        veto: impl FnOnce(&EntryDef<'a>, &[u8]) -> Result<(), AbortCode>,
    ) -> Result<(), AbortCode> {
        let i = self.find(addr)?;
        if !self.defs[i].access.writable() {
            return Err(AbortCode::ReadOnly);
        }
        self.check_write(i, data)?;
        veto(&self.defs[i], data)?;
        self.store(i, data);
        Ok(())
    }

    /// A local write by device code: no access check (read-only values are the device's to
    /// set), but type length and limits are checked.
    pub fn set_raw(&mut self, at: impl Locate, data: &[u8]) -> Result<(), AbortCode> {
        let i = self.locate(at)?;
        self.check_write(i, data)?;
        self.store(i, data);
        Ok(())
    }

    /// Sets a value of any kind (local write, see [`ObjectDictionary::set_raw`]).
    pub fn set_value(&mut self, at: impl Locate, v: Value<'_>) -> Result<(), AbortCode> {
        let i = self.locate(at)?;
        let dt = self.slots[i].data_type;
        let mut buf = [0u8; 8];
        if let Value::Bytes(b) = v {
            return self.set_raw(at, b);
        }
        let n = encode_value(dt, &v, &mut buf)?;
        self.set_raw(at, &buf[..n])
    }

    fn get_unsigned(&self, at: impl Locate, max_bits: u32) -> Result<u64, AbortCode> {
        let s = &self.slots[self.locate(at)?];
        if s.class != TypeClass::Unsigned || u32::from(s.bits) > max_bits {
            return Err(AbortCode::TypeMismatch);
        }
        Ok(le_u64(&self.arena[s.offset..s.offset + s.len]))
    }

    fn get_signed(&self, at: impl Locate, max_bits: u32) -> Result<i64, AbortCode> {
        let s = &self.slots[self.locate(at)?];
        let bits = u32::from(s.bits);
        if s.class != TypeClass::Signed || bits > max_bits {
            return Err(AbortCode::TypeMismatch);
        }
        // Sign-extend the stored little-endian bytes (device code reads actual values every
        // cycle: no general decode on this path).
        let raw = le_u64(&self.arena[s.offset..s.offset + s.len]);
        let shift = 64 - bits.clamp(1, 64);
        Ok(((raw << shift) as i64) >> shift)
    }

    /// One lookup, the type rule, the encoding, limits only where the entry has them: device
    /// code publishes its actual values through here every cycle.
    fn set_integer(
        &mut self,
        at: impl Locate,
        v: Value<'_>,
        class: TypeClass,
        max_bits: u32,
    ) -> Result<(), AbortCode> {
        let i = self.locate(at)?;
        let slot = &self.slots[i];
        if slot.class != class || u32::from(slot.bits) > max_bits {
            return Err(AbortCode::TypeMismatch);
        }
        self.store_int(i, v)
    }

    /// Range check, limits where the entry has them, store: an integer value into slot `i`.
    fn store_int(&mut self, i: usize, v: Value<'_>) -> Result<(), AbortCode> {
        let slot = self.slots[i];
        let dt = slot.data_type;
        let raw = int_to_raw(dt, &v)?;
        let buf = raw.to_le_bytes();
        let n = dt.size().unwrap_or(8).min(8);
        if slot.checked {
            self.check_write(i, &buf[..n])?;
        }
        self.store(i, &buf[..n]);
        Ok(())
    }

    /// Sets an integer entry of any width and signedness from `v` (local write: the value must
    /// fit the entry's type and limits, access is not checked). For device code that publishes
    /// many values of different types.
    pub fn set_int(&mut self, at: impl Locate, v: i64) -> Result<(), AbortCode> {
        let i = self.locate(at)?;
        self.set_int_at(i, v)
    }

    fn set_unsigned(&mut self, at: impl Locate, v: u64, max_bits: u32) -> Result<(), AbortCode> {
        self.set_integer(at, Value::Unsigned(v), TypeClass::Unsigned, max_bits)
    }

    fn set_signed(&mut self, at: impl Locate, v: i64, max_bits: u32) -> Result<(), AbortCode> {
        self.set_integer(at, Value::Signed(v), TypeClass::Signed, max_bits)
    }

    /// A REAL32.
    pub fn get_f32(&self, addr: impl Locate) -> Result<f32, AbortCode> {
        match self.value(addr)? {
            Value::Real32(v) => Ok(v),
            _ => Err(AbortCode::TypeMismatch),
        }
    }
    /// Sets a REAL32 or REAL64 (local write, limits checked).
    pub fn set_f32(&mut self, addr: impl Locate, v: f32) -> Result<(), AbortCode> {
        self.set_value(addr, Value::Real32(v))
    }
    /// A REAL64.
    pub fn get_f64(&self, addr: impl Locate) -> Result<f64, AbortCode> {
        match self.value(addr)? {
            Value::Real64(v) => Ok(v),
            _ => Err(AbortCode::TypeMismatch),
        }
    }
    /// Sets a REAL64 (local write, limits checked).
    pub fn set_f64(&mut self, addr: impl Locate, v: f64) -> Result<(), AbortCode> {
        self.set_value(addr, Value::Real64(v))
    }
    /// A BOOLEAN.
    pub fn get_bool(&self, addr: impl Locate) -> Result<bool, AbortCode> {
        Ok(self.get_unsigned(addr, 1)? != 0)
    }
    /// Sets a BOOLEAN.
    pub fn set_bool(&mut self, addr: impl Locate, v: bool) -> Result<(), AbortCode> {
        self.set_unsigned(addr, v as u64, 1)
    }
}

macro_rules! typed_access {
    ($($get:ident, $set:ident, $t:ty, $bits:literal, $getter:ident, $setter:ident;)*) => {
        impl<'a, const N: usize, const BYTES: usize> ObjectDictionary<'a, N, BYTES> {
            $(
                #[doc = concat!("The value as `", stringify!($t), "`: `TypeMismatch` unless the entry's type fits in ", stringify!($bits), " bits of that signedness.")]
                pub fn $get(&self, at: impl Locate) -> Result<$t, AbortCode> {
                    Ok(self.$getter(at, $bits)? as $t)
                }
                #[doc = concat!("Sets the value from `", stringify!($t), "`: same type rule as the getter, and the value must fit the entry (local write: limits checked, access not).")]
                pub fn $set(&mut self, at: impl Locate, v: $t) -> Result<(), AbortCode> {
                    self.$setter(at, v as _, $bits)
                }
            )*
        }
    };
}

typed_access! {
    get_u8, set_u8, u8, 8, get_unsigned, set_unsigned;
    get_u16, set_u16, u16, 16, get_unsigned, set_unsigned;
    get_u32, set_u32, u32, 32, get_unsigned, set_unsigned;
    get_u64, set_u64, u64, 64, get_unsigned, set_unsigned;
    get_i8, set_i8, i8, 8, get_signed, set_signed;
    get_i16, set_i16, i16, 16, get_signed, set_signed;
    get_i32, set_i32, i32, 32, get_signed, set_signed;
    get_i64, set_i64, i64, 64, get_signed, set_signed;
}

impl<const N: usize, const BYTES: usize> ObjectAccess for ObjectDictionary<'_, N, BYTES> {
    fn size(&self, addr: Address) -> Result<usize, AbortCode> {
        let s = &self.slots[self.find(addr)?];
        Ok(s.len)
    }

    fn read(&mut self, addr: Address, offset: usize, buf: &mut [u8]) -> Result<usize, AbortCode> {
        let i = self.find(addr)?;
        let s = &self.slots[i];
        if !self.defs[i].access.readable() {
            return Err(AbortCode::WriteOnly);
        }
        let value = &self.arena[s.offset..s.offset + s.len];
        let rest = value.get(offset..).unwrap_or(&[]);
        let n = rest.len().min(buf.len());
        buf[..n].copy_from_slice(&rest[..n]);
        Ok(n)
    }

    fn write(&mut self, addr: Address, data: &[u8]) -> Result<(), AbortCode> {
        self.write_with(addr, data, |_, _| Ok(()))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const CW: Address = Address::new(0x6040, 0);
    const SW: Address = Address::new(0x6041, 0);
    const TARGET: Address = Address::new(0x607A, 0);
    const NAME: Address = Address::new(0x1008, 0);
    const PASS: Address = Address::new(0x2000, 0);
    const ID24: Address = Address::new(0x2001, 1);
    const FLAG: Address = Address::new(0x2002, 0);

    fn od() -> ObjectDictionary<'static, 16, 64> {
        let mut od = ObjectDictionary::new();
        od.insert_all(&[
            EntryDef::new(TARGET, "target", DataType::Integer32, AccessType::Rww)
                .mappable()
                .limits(Value::Signed(-1000), Value::Signed(1000)),
            EntryDef::new(SW, "statusword", DataType::Unsigned16, AccessType::Ro).mappable(),
            EntryDef::new(CW, "controlword", DataType::Unsigned16, AccessType::Rww)
                .mappable()
                .default_value(Value::Unsigned(6)),
            EntryDef::new(NAME, "name", DataType::VisibleString, AccessType::Const)
                .capacity(8)
                .default_value(Value::Bytes(b"TLC")),
            EntryDef::new(PASS, "password", DataType::Unsigned32, AccessType::Wo),
            EntryDef::new(ID24, "i24", DataType::Integer24, AccessType::Rw)
                .default_value(Value::Signed(-2)),
            EntryDef::new(FLAG, "flag", DataType::Boolean, AccessType::Rw),
        ])
        .unwrap();
        od
    }

    #[test]
    fn resolved_handles_reach_their_entry_even_when_stale() {
        let mut d = od();
        let cw = d.resolve(CW);
        let target = d.resolve(TARGET);
        assert_eq!(cw.address(), CW);
        assert_eq!(d.get_u16(cw), Ok(6));
        d.set_u16(cw, 0x0F).unwrap();
        assert_eq!(d.get_u16(CW), Ok(0x0F));
        // Limits and types are checked through a handle as through the address.
        assert_eq!(d.set_i32(target, 2000), Err(AbortCode::ValueTooHigh));
        assert_eq!(d.get_u16(target), Err(AbortCode::TypeMismatch));
        // Inserts before them move every entry: the handles still find theirs.
        d.insert(EntryDef::new(
            Address::new(0x1000, 0),
            "device type",
            DataType::Unsigned32,
            AccessType::Ro,
        ))
        .unwrap();
        d.insert(EntryDef::new(
            Address::new(0x1001, 0),
            "error",
            DataType::Unsigned8,
            AccessType::Ro,
        ))
        .unwrap();
        assert_eq!(d.get_u16(cw), Ok(0x0F));
        d.set_i32(target, -5).unwrap();
        assert_eq!(d.get_i32(TARGET), Ok(-5));
        // A handle from another dictionary never reaches a different entry there.
        let other = od();
        assert_eq!(other.get_u16(cw), Ok(6));
        assert_eq!(other.get_i32(target), Ok(0));
        // A handle of a missing object is refused as its address is.
        let missing = d.resolve(Address::new(0x6040, 1));
        assert_eq!(d.get_u16(missing), Err(AbortCode::NoSubIndex));
        assert_eq!(
            d.get_u16(d.resolve(Address::new(0x5555, 0))),
            Err(AbortCode::NoObject)
        );
    }

    #[test]
    fn lookup_errors_distinguish_object_and_sub() {
        let mut od = od();
        let mut b = [0u8; 4];
        assert_eq!(
            od.read(Address::new(0x6042, 0), 0, &mut b),
            Err(AbortCode::NoObject)
        );
        assert_eq!(
            od.read(Address::new(0x6040, 1), 0, &mut b),
            Err(AbortCode::NoSubIndex)
        );
        assert_eq!(
            od.read(Address::new(0x2001, 0), 0, &mut b),
            Err(AbortCode::NoSubIndex)
        );
        assert_eq!(
            od.read(Address::new(0x2001, 2), 0, &mut b),
            Err(AbortCode::NoSubIndex)
        );
        assert_eq!(od.read(CW, 0, &mut b), Ok(2));
        assert_eq!(b[..2], [6, 0]);
        // Entries are kept sorted whatever the insertion order.
        let addrs: heapless::Vec<Address, 16> = od.entries().map(|e| e.addr).collect();
        assert!(addrs.windows(2).all(|w| w[0] < w[1]));
    }

    #[test]
    fn access_length_and_limits() {
        let mut od = od();
        let mut b = [0u8; 4];
        assert_eq!(od.read(PASS, 0, &mut b), Err(AbortCode::WriteOnly));
        assert_eq!(od.write(SW, &[0, 0]), Err(AbortCode::ReadOnly));
        assert_eq!(od.write(NAME, b"x"), Err(AbortCode::ReadOnly));
        assert_eq!(od.write(CW, &[1]), Err(AbortCode::TooShort));
        assert_eq!(od.write(CW, &[1, 2, 3]), Err(AbortCode::TooLong));
        assert_eq!(
            od.write(TARGET, &1001i32.to_le_bytes()),
            Err(AbortCode::ValueTooHigh)
        );
        assert_eq!(
            od.write(TARGET, &(-1001i32).to_le_bytes()),
            Err(AbortCode::ValueTooLow)
        );
        assert_eq!(od.write(TARGET, &(-1000i32).to_le_bytes()), Ok(()));
        assert_eq!(od.get_i32(TARGET), Ok(-1000));
        assert_eq!(od.write(FLAG, &[2]), Err(AbortCode::InvalidValue));
        assert_eq!(od.write(PASS, &[1, 2, 3, 4]), Ok(()));
        // A refused write leaves the value alone.
        assert_eq!(od.get_i32(TARGET), Ok(-1000));
    }

    #[test]
    fn typed_access_and_local_writes() {
        let mut od = od();
        assert_eq!(od.get_i32(ID24), Ok(-2));
        assert_eq!(od.raw(ID24), Ok(&[0xFE, 0xFF, 0xFF][..]));
        assert_eq!(od.set_i32(ID24, 1 << 23), Err(AbortCode::ValueTooHigh));
        assert_eq!(od.set_i32(ID24, -(1 << 23)), Ok(()));
        assert_eq!(od.get_i16(ID24), Err(AbortCode::TypeMismatch));
        assert_eq!(od.get_u32(TARGET), Err(AbortCode::TypeMismatch));
        // Device code sets its read-only statusword.
        assert_eq!(od.set_u16(SW, 0x0237), Ok(()));
        assert_eq!(od.get_u16(SW), Ok(0x0237));
        assert_eq!(od.get_u32(SW), Ok(0x0237));
        // A wider setter works while the value fits the entry's type.
        assert_eq!(od.set_u32(SW, 0x1_0000), Err(AbortCode::ValueTooHigh));
        assert_eq!(od.set_i32(SW, 1), Err(AbortCode::TypeMismatch));
        assert_eq!(od.set_i32(TARGET, 5000), Err(AbortCode::ValueTooHigh));
        assert_eq!(od.set_bool(FLAG, true), Ok(()));
        assert_eq!(od.get_bool(FLAG), Ok(true));
        // Variable-length values report their current size.
        assert_eq!(od.size(NAME), Ok(3));
        let mut b = [0u8; 8];
        assert_eq!(od.read(NAME, 1, &mut b), Ok(2));
        assert_eq!(&b[..2], b"LC");
        assert_eq!(od.set_raw(NAME, b"123456789"), Err(AbortCode::TooLong));
        od.set_raw(NAME, b"TLC53x").unwrap();
        od.reset_to_defaults();
        assert_eq!(od.raw(NAME), Ok(&b"TLC"[..]));
        assert_eq!(od.get_u16(CW), Ok(6));
    }

    #[test]
    fn reals() {
        let r = Address::new(0x2100, 0);
        let mut od: ObjectDictionary<'static, 2, 16> = ObjectDictionary::new();
        od.insert(
            EntryDef::new(r, "gain", DataType::Real32, AccessType::Rw)
                .limits(Value::Real32(0.0), Value::Real32(10.0)),
        )
        .unwrap();
        assert_eq!(od.get_f32(r), Ok(0.0));
        assert_eq!(od.write(r, &2.5f32.to_le_bytes()), Ok(()));
        assert_eq!(od.get_f32(r), Ok(2.5));
        assert_eq!(od.set_f32(r, 11.0), Err(AbortCode::ValueTooHigh));
        assert_eq!(od.get_f64(r), Err(AbortCode::TypeMismatch));
    }

    #[test]
    fn capacity_errors() {
        let mut od: ObjectDictionary<'static, 2, 6> = ObjectDictionary::new();
        od.insert(EntryDef::new(
            CW,
            "cw",
            DataType::Unsigned16,
            AccessType::Rw,
        ))
        .unwrap();
        assert_eq!(
            od.insert(EntryDef::new(
                CW,
                "cw",
                DataType::Unsigned16,
                AccessType::Rw
            )),
            Err(OdError::Duplicate(CW))
        );
        assert_eq!(
            od.insert(EntryDef::new(
                TARGET,
                "t",
                DataType::Integer64,
                AccessType::Rw
            )),
            Err(OdError::ArenaFull {
                addr: TARGET,
                needed: 8,
                available: 4
            })
        );
        assert_eq!(
            od.insert(
                EntryDef::new(SW, "sw", DataType::Unsigned8, AccessType::Rw)
                    .default_value(Value::Unsigned(256))
            ),
            Err(OdError::BadDefault {
                addr: SW,
                code: AbortCode::ValueTooHigh
            })
        );
        od.insert(EntryDef::new(
            SW,
            "sw",
            DataType::Unsigned32,
            AccessType::Rw,
        ))
        .unwrap();
        assert_eq!(
            od.insert(EntryDef::new(FLAG, "f", DataType::Boolean, AccessType::Rw)),
            Err(OdError::Full {
                capacity: 2,
                addr: FLAG
            })
        );
    }

    #[test]
    fn veto_runs_after_own_checks() {
        let mut od = od();
        let mut asked = 0;
        let r = od.write_with(CW, &[1], |_, _| {
            asked += 1;
            Ok(())
        });
        assert_eq!(r, Err(AbortCode::TooShort));
        assert_eq!(asked, 0);
        let r = od.write_with(CW, &[0x0F, 0], |def, new| {
            assert_eq!(def.addr, CW);
            assert_eq!(new, &[0x0F, 0]);
            Err(AbortCode::Other(0x0800_1234))
        });
        assert_eq!(r, Err(AbortCode::Other(0x0800_1234)));
        assert_eq!(od.get_u16(CW), Ok(6));
    }

    #[test]
    fn data_type_codes_round_trip() {
        for code in 0..0x30u16 {
            if let Some(dt) = DataType::from_code(code) {
                assert_eq!(dt.code(), code);
            }
        }
        assert_eq!(DataType::from_code(0x0017), None);
        assert_eq!(DataType::Unsigned24.size(), Some(3));
        assert_eq!(DataType::Domain.size(), None);
        assert!(AccessType::Rwr.tpdo_direction() && !AccessType::Rwr.rpdo_direction());
        assert!(AccessType::Rww.rpdo_direction() && !AccessType::Rww.tpdo_direction());
        assert!(!AccessType::Const.writable() && AccessType::Const.readable());
    }
}
