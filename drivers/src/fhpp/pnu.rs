//! Parameter numbers (PNUs): definition tables of the three devices, lookup by (PNU,
//! sub-index), and the write check that yields the device's FPC error number.
//!
//! Sources: MTR-DCI digest §5, §6.6, §8.2; EMCA digest §3–§7; CMMO-ST digest §4–§6. Where the
//! digests give no default, the table says 0 (or the first legal value) and the simulator may
//! override it; where a default depends on the MTR-DCI motor size, the table holds size 42 with
//! gear G7 on a DMES-25 (see [`super::units::MtrSize`] for the others).
//!
//! Sub-index conventions differ: on the MTR-DCI's classic FPC a simple variable has IND 0 and
//! record n is IND n + 1; on the EFPC devices a simple variable has sub-index 1 (0 is accepted
//! too) and record n is sub-index n (see [`record_subindex`]).

use super::fpc::{Channel, ErrorKind, Param, Value};
use super::{ControlMode, Variant};
use crate::canopen::Address;
use crate::hash_index::HashIndex;

/// The data type of a parameter.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum DataType {
    /// uint8.
    U8,
    /// int8.
    I8,
    /// uint16.
    U16,
    /// int16.
    I16,
    /// uint32.
    U32,
    /// int32.
    I32,
    /// One character of a string (one sub-index per character).
    Char,
}

impl DataType {
    /// The smallest value of the type.
    pub const fn min(self) -> i64 {
        match self {
            DataType::U8 | DataType::U16 | DataType::U32 | DataType::Char => 0,
            DataType::I8 => i8::MIN as i64,
            DataType::I16 => i16::MIN as i64,
            DataType::I32 => i32::MIN as i64,
        }
    }
    /// The largest value of the type.
    pub const fn max(self) -> i64 {
        match self {
            DataType::U8 | DataType::Char => u8::MAX as i64,
            DataType::I8 => i8::MAX as i64,
            DataType::U16 => u16::MAX as i64,
            DataType::I16 => i16::MAX as i64,
            DataType::U32 => u32::MAX as i64,
            DataType::I32 => i32::MAX as i64,
        }
    }
    const fn signed(self) -> bool {
        matches!(self, DataType::I8 | DataType::I16 | DataType::I32)
    }
    /// The value as it travels: classic FPC in the type's own width, EFPC always 32 bits
    /// (two's complement for signed types).
    pub const fn encode(self, v: i64, channel: Channel) -> Value {
        match (channel, self) {
            (Channel::Classic, DataType::U8 | DataType::I8 | DataType::Char) => {
                Value::Byte(v as u8)
            }
            (Channel::Classic, DataType::U16 | DataType::I16) => Value::Word(v as u16),
            _ => Value::Dword(v as u32),
        }
    }
    /// The number a transferred value stands for, sign-extended from its width if the type is
    /// signed.
    pub const fn decode(self, v: Value) -> i64 {
        let s = self.signed();
        match v {
            Value::Byte(b) if s => b as i8 as i64,
            Value::Byte(b) => b as i64,
            Value::Word(w) if s => w as i16 as i64,
            Value::Word(w) => w as i64,
            Value::Dword(d) if s => d as i32 as i64,
            Value::Dword(d) => d as i64,
        }
    }
    /// Whether a classic FPC value of this width fits the type (ReqID width = type width).
    pub const fn width_matches(self, v: Value) -> bool {
        matches!(
            (self, v),
            (DataType::U8 | DataType::I8 | DataType::Char, Value::Byte(_))
                | (DataType::U16 | DataType::I16, Value::Word(_))
                | (DataType::U32 | DataType::I32, Value::Dword(_))
        )
    }
}

/// Who may write a parameter.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum Access {
    /// Read only.
    Ro,
    /// Write only.
    Wo,
    /// Read and write at any time (EMCA/CMMO-ST "rw1").
    Rw,
    /// Read; write only with the output stage off (EMCA/CMMO-ST "rw2").
    Rw2,
}

/// One parameter (or a run of its sub-indices sharing type, access and limits).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub struct ParamDef {
    /// The PNU.
    pub pnu: u16,
    /// The first sub-index this entry covers.
    pub first_sub: u8,
    /// The last sub-index this entry covers.
    pub last_sub: u8,
    /// The manual's name.
    pub name: &'static str,
    /// The data type.
    pub dtype: DataType,
    /// The access.
    pub access: Access,
    /// The factory default.
    pub default: i64,
    /// The lowest value a write may set.
    pub min: i64,
    /// The highest value a write may set.
    pub max: i64,
}

impl ParamDef {
    /// The CANopen SDO address of the parameter's sub-index: 2000h + PNU (all three devices in
    /// FHPP mode; the MTR-DCI's CI aliases such as 20ECh for PNU 404 are not modelled).
    pub const fn sdo_address(&self, sub: u8) -> Address {
        Address::new(0x2000 + self.pnu, sub)
    }
    /// Whether this entry covers sub-index `sub`.
    pub const fn covers(&self, sub: u8) -> bool {
        sub >= self.first_sub && sub <= self.last_sub
    }
}

/// Why a parameter access is refused; [`ParamError::kind`] gives the FPC error.
#[derive(Debug, Clone, Copy, PartialEq, Eq, thiserror::Error)]
pub enum ParamError {
    /// No such PNU.
    #[error("PNU {pnu} does not exist")]
    NoSuchPnu {
        /// The PNU.
        pnu: u16,
    },
    /// The PNU exists, the sub-index does not.
    #[error("PNU {pnu} has no sub-index {sub}")]
    BadSubindex {
        /// The PNU.
        pnu: u16,
        /// The sub-index.
        sub: u8,
    },
    /// Write to a read-only parameter.
    #[error("PNU {pnu} is read-only")]
    ReadOnly {
        /// The PNU.
        pnu: u16,
    },
    /// Read of a write-only parameter.
    #[error("PNU {pnu} is write-only")]
    WriteOnly {
        /// The PNU.
        pnu: u16,
    },
    /// A classic FPC value of the wrong width for the type.
    #[error("PNU {pnu}: value width does not match its type {dtype:?}")]
    WrongType {
        /// The PNU.
        pnu: u16,
        /// The parameter's type.
        dtype: DataType,
    },
    /// The value is outside the parameter's limits.
    #[error("PNU {pnu}:{sub}: value {value} outside {min}..={max}")]
    OutOfRange {
        /// The PNU.
        pnu: u16,
        /// The sub-index.
        sub: u8,
        /// The value written.
        value: i64,
        /// The lower limit.
        min: i64,
        /// The upper limit.
        max: i64,
    },
    /// An rw2 parameter written while the output stage is on.
    #[error("PNU {pnu} may be written only with the output stage off")]
    StageOn {
        /// The PNU.
        pnu: u16,
    },
}

impl ParamError {
    /// The FPC error kind (see [`ErrorKind::number`] for the device's number: an out-of-range
    /// write is EFPC 0x02 on EMCA/CMMO-ST and classic 22 on the MTR-DCI).
    pub const fn kind(&self) -> ErrorKind {
        match self {
            ParamError::NoSuchPnu { .. } => ErrorKind::NoSuchPnu,
            ParamError::BadSubindex { .. } => ErrorKind::BadSubindex,
            ParamError::ReadOnly { .. } => ErrorKind::ReadOnly,
            ParamError::WriteOnly { .. } => ErrorKind::WriteOnly,
            ParamError::WrongType { .. } => ErrorKind::WrongType,
            ParamError::OutOfRange { .. } => ErrorKind::OutOfRange,
            ParamError::StageOn { .. } => ErrorKind::NotInThisState,
        }
    }
    /// The device's FPC error number.
    pub const fn fpc_number(&self, variant: Variant) -> u16 {
        self.kind().number(variant.parameter_channel())
    }
}

/// A device's parameter table: its own entries, searched first, then the FHPP family entries
/// it shares with its sibling.
#[derive(Debug, Clone, Copy)]
pub struct Table {
    /// The variant.
    pub variant: Variant,
    specific: &'static [ParamDef],
    common: &'static [ParamDef],
}

impl Table {
    /// The table of `variant`.
    pub const fn of(variant: Variant) -> Table {
        match variant {
            Variant::MtrDci => Table {
                variant,
                specific: MTR_DCI,
                common: &[],
            },
            Variant::Emca => Table {
                variant,
                specific: EMCA,
                common: FHPP_FAMILY,
            },
            Variant::CmmoSt => Table {
                variant,
                specific: CMMO_ST,
                common: FHPP_FAMILY,
            },
        }
    }

    /// How many values the table holds (sum of the entries' sub-index counts): the least `N`
    /// of a [`ParamStore`].
    pub fn value_count(&self) -> usize {
        self.entries()
            .map(|d| usize::from(d.last_sub - d.first_sub) + 1)
            .sum()
    }

    /// Every entry (specific ones first; a common entry shadowed by a specific one for the same
    /// PNU is still listed).
    pub fn entries(&self) -> impl Iterator<Item = &'static ParamDef> + use<> {
        self.specific.iter().chain(self.common.iter())
    }

    /// The `i`-th of [`Table::entries`].
    fn entry(&self, i: usize) -> Option<&'static ParamDef> {
        match self.specific.get(i) {
            Some(d) => Some(d),
            None => self.common.get(i - self.specific.len()),
        }
    }

    /// The entry for `param`. On the EFPC devices sub-index 0 of a simple variable means 1.
    pub fn lookup(&self, param: Param) -> Result<&'static ParamDef, ParamError> {
        let in_specific = self.specific.iter().any(|d| d.pnu == param.pnu);
        let list = if in_specific {
            self.specific
        } else {
            self.common
        };
        let mut seen = false;
        for d in list.iter().filter(|d| d.pnu == param.pnu) {
            seen = true;
            let simple_efpc =
                self.variant != Variant::MtrDci && d.first_sub == 1 && d.last_sub == 1;
            if d.covers(param.sub) || (simple_efpc && param.sub == 0) {
                return Ok(d);
            }
        }
        if seen {
            Err(ParamError::BadSubindex {
                pnu: param.pnu,
                sub: param.sub,
            })
        } else {
            Err(ParamError::NoSuchPnu { pnu: param.pnu })
        }
    }

    /// Checks a read: the parameter exists and is readable.
    pub fn check_read(&self, param: Param) -> Result<&'static ParamDef, ParamError> {
        let d = self.lookup(param)?;
        if d.access == Access::Wo {
            return Err(ParamError::WriteOnly { pnu: d.pnu });
        }
        Ok(d)
    }

    /// Checks a write of the transferred `value` with the output stage on or off; returns the
    /// entry and the number the value stands for.
    pub fn check_write(
        &self,
        param: Param,
        value: Value,
        stage_on: bool,
    ) -> Result<(&'static ParamDef, i64), ParamError> {
        let d = self.lookup(param)?;
        match d.access {
            Access::Ro => return Err(ParamError::ReadOnly { pnu: d.pnu }),
            Access::Rw2 if stage_on => return Err(ParamError::StageOn { pnu: d.pnu }),
            _ => {}
        }
        if self.variant.parameter_channel() == Channel::Classic && !d.dtype.width_matches(value) {
            return Err(ParamError::WrongType {
                pnu: d.pnu,
                dtype: d.dtype,
            });
        }
        let v = d.dtype.decode(value);
        if v < d.min || v > d.max {
            return Err(ParamError::OutOfRange {
                pnu: d.pnu,
                sub: param.sub,
                value: v,
                min: d.min,
                max: d.max,
            });
        }
        Ok((d, v))
    }
}

/// [`ParamStore::new`] was given too little room for the table.
#[derive(Debug, Clone, Copy, PartialEq, Eq, thiserror::Error)]
#[error("parameter store holds {capacity} values, the table needs {needed}")]
pub struct CapacityError {
    /// Values the table needs.
    pub needed: usize,
    /// The store's capacity `N`.
    pub capacity: usize,
}

/// One (PNU, sub-index) of a [`ParamStore`]: its table entry (in [`Table::entries`] order) and
/// its value's place.
#[derive(Debug, Clone, Copy)]
struct Key {
    /// `pnu << 8 | sub`: sorts as (PNU, sub-index) and compares in one step.
    key: u32,
    def: u16,
    value: u16,
}

/// The search key of a (PNU, sub-index).
const fn param_key(pnu: u16, sub: u8) -> u32 {
    (pnu as u32) << 8 | sub as u32
}

/// A device's parameter values: one `i64` per (PNU, sub-index) of its [`Table`], starting at
/// the defaults; [`fpc::Parameters`](super::fpc::Parameters) for the FPC [`Server`](super::fpc::Server) with the access, type,
/// range, rw2 and device-control checks. `N` must be at least [`Table::value_count`].
#[derive(Debug, Clone)]
pub struct ParamStore<const N: usize> {
    table: Table,
    values: heapless::Vec<i64, N>,
    /// Where each (PNU, sub-index) of the table keeps its value, sorted by PNU and sub-index.
    keys: heapless::Vec<Key, N>,
    /// A hash index over `keys` ([`HashIndex`]): a key it does not hold is found by a binary
    /// search.
    hashed: HashIndex<N>,
    /// The output stage is on: rw2 writes are refused.
    pub stage_on: bool,
    /// The fieldbus holds device control: without it writes are refused ("no control").
    pub fieldbus_control: bool,
}

impl<const N: usize> ParamStore<N> {
    /// A store with every value at its default.
    pub fn new(variant: Variant) -> Result<ParamStore<N>, CapacityError> {
        let table = Table::of(variant);
        let mut values = heapless::Vec::new();
        for d in table.entries() {
            for _ in d.first_sub..=d.last_sub {
                values.push(d.default).map_err(|_| CapacityError {
                    needed: table.value_count(),
                    capacity: N,
                })?;
            }
        }
        let mut store = ParamStore {
            table,
            values,
            keys: heapless::Vec::new(),
            hashed: HashIndex::new(),
            stage_on: false,
            fieldbus_control: true,
        };
        // Every (PNU, sub-index) the table resolves to one of its values, sorted.
        for (def, d) in table.entries().enumerate() {
            for sub in d.first_sub..=d.last_sub {
                let param = Param::new(d.pnu, sub);
                if let Ok((found, value)) = store.index_by_scan(param)
                    && core::ptr::eq(found, d)
                    && let (Ok(def), Ok(value)) = (u16::try_from(def), u16::try_from(value))
                {
                    // At most one key per value: the capacity is the values'.
                    let _ = store.keys.push(Key {
                        key: param_key(d.pnu, sub),
                        def,
                        value,
                    });
                }
            }
        }
        store.keys.sort_unstable_by_key(|k| k.key);
        store.hashed.rebuild(store.keys.iter().map(|k| k.key));
        Ok(store)
    }

    /// The table.
    pub const fn table(&self) -> &Table {
        &self.table
    }

    fn index(&self, param: Param) -> Result<(&'static ParamDef, usize), ParamError> {
        // The simulated drives read and write tens of values every control cycle: the hash
        // index or a binary search of the sorted keys instead of two scans of the table. What
        // the keys do not hold exactly (sub-index 0 of a simple EFPC variable, errors) takes
        // the scans.
        let key = param_key(param.pnu, param.sub);
        if let Ok(k) = self.hashed.search(key, &self.keys, |k| k.key)
            && let Some(d) = self.table.entry(usize::from(self.keys[k].def))
        {
            return Ok((d, usize::from(self.keys[k].value)));
        }
        self.index_by_scan(param)
    }

    /// [`ParamStore::index`] by scanning the table: the definition of what the keys hold.
    fn index_by_scan(&self, param: Param) -> Result<(&'static ParamDef, usize), ParamError> {
        let d = self.table.lookup(param)?;
        let mut offset = 0usize;
        for e in self.table.entries() {
            if core::ptr::eq(e, d) {
                let sub = if param.sub < d.first_sub {
                    d.first_sub
                } else {
                    param.sub
                };
                return Ok((d, offset + usize::from(sub - d.first_sub)));
            }
            offset += usize::from(e.last_sub - e.first_sub) + 1;
        }
        Err(ParamError::NoSuchPnu { pnu: param.pnu })
    }

    /// The value of `param`, whatever its access (the device's own view).
    pub fn get(&self, param: Param) -> Result<i64, ParamError> {
        let (_, i) = self.index(param)?;
        self.values
            .get(i)
            .copied()
            .ok_or(ParamError::NoSuchPnu { pnu: param.pnu })
    }

    /// Sets `param` from inside the device (live values such as PNU 1041, diagnostics),
    /// bypassing access and range checks; the value is limited to the type's range.
    pub fn set(&mut self, param: Param, value: i64) -> Result<(), ParamError> {
        let (d, i) = self.index(param)?;
        let v = value.clamp(d.dtype.min(), d.dtype.max());
        match self.values.get_mut(i) {
            Some(slot) => {
                *slot = v;
                Ok(())
            }
            None => Err(ParamError::NoSuchPnu { pnu: param.pnu }),
        }
    }

    /// Sets every value back to its default.
    pub fn reset_defaults(&mut self) {
        let mut i = 0;
        for d in self.table.entries() {
            for _ in d.first_sub..=d.last_sub {
                if let Some(slot) = self.values.get_mut(i) {
                    *slot = d.default;
                }
                i += 1;
            }
        }
    }
}

impl<const N: usize> super::fpc::Parameters for ParamStore<N> {
    fn read(&mut self, param: Param) -> Result<Value, ErrorKind> {
        let d = self.table.check_read(param).map_err(|e| e.kind())?;
        let v = self.get(param).map_err(|e| e.kind())?;
        Ok(d.dtype.encode(v, self.table.variant.parameter_channel()))
    }

    fn write(&mut self, param: Param, value: Value) -> Result<(), ErrorKind> {
        if !self.fieldbus_control {
            return Err(ErrorKind::NoControl);
        }
        let (_, v) = self
            .table
            .check_write(param, value, self.stage_on)
            .map_err(|e| e.kind())?;
        self.set(param, v).map_err(|e| e.kind())
    }
}

/// The sub-index of record `record` in the record-table PNUs (401..), or `None` past the
/// device's records: MTR-DCI record n → IND n + 1 (record 0, homing, is IND 1); EMCA/CMMO-ST
/// record n → sub-index n (1..=64; homing has no record row).
pub const fn record_subindex(variant: Variant, record: u8) -> Option<u8> {
    match variant.device().records {
        Some(r) => r.subindex(record),
        None => None,
    }
}

/// RCB1, record control byte 1 (PNU 401). MTR-DCI: only bit 0 (ABS); bits 1..7 reserved.
/// EMCA/CMMO-ST: B0 ABS, B1..B2 COM (11 = invalid record), B4 REL, B5 XLIM.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Default)]
pub struct Rcb1 {
    /// B0: 1 = relative setpoint.
    pub relative: bool,
    /// B1..B2 COM: the record's control mode ([`ControlMode::Reserved`] = invalid record).
    pub com: ControlMode,
    /// B4 REL: a relative setpoint refers to 0 = the last setpoint, 1 = the actual position.
    pub rel_to_actual: bool,
    /// B5 XLIM: 1 = stroke monitoring off (speed/force records).
    pub xlim_off: bool,
}

impl Rcb1 {
    /// Decodes PNU 401 with `variant`'s layout (MTR-DCI: bit 0 only).
    pub const fn from_byte(b: u8, variant: Variant) -> Rcb1 {
        match variant {
            Variant::MtrDci => Rcb1 {
                relative: b & 1 != 0,
                com: ControlMode::Position,
                rel_to_actual: false,
                xlim_off: false,
            },
            Variant::Emca | Variant::CmmoSt => Rcb1 {
                relative: b & 1 != 0,
                com: ControlMode::from_bits(b >> 1),
                rel_to_actual: b & 0x10 != 0,
                xlim_off: b & 0x20 != 0,
            },
        }
    }
    /// Encodes PNU 401 with `variant`'s layout.
    pub const fn to_byte(self, variant: Variant) -> u8 {
        let abs = self.relative as u8;
        match variant {
            Variant::MtrDci => abs,
            Variant::Emca | Variant::CmmoSt => {
                abs | (self.com.bits() << 1)
                    | ((self.rel_to_actual as u8) << 4)
                    | ((self.xlim_off as u8) << 5)
            }
        }
    }
}

/// The step-enabling condition of a record chain (RCB2 bits 0..6, PNU 402).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Default)]
pub enum StepCondition {
    /// 0: end of the chain.
    #[default]
    Inactive,
    /// 1: motion complete (then PNU 426 of the record is a delay, CMMO-ST reading).
    Mc,
    /// 20: the position comparator (430/431/432) is active.
    Position,
    /// 21: the velocity comparator (433/434/435) is active.
    Velocity,
    /// 22: the force comparator (436/437/438) is active.
    Force,
    /// 23: the time comparator (439/440) is active.
    Time,
    /// Any other code: an invalid record (CMMO-ST digest decision: 3Fh).
    Invalid(u8),
}

/// RCB2 (PNU 402): record chaining. EMCA only: B7 "activate record sequencing"; chaining is
/// active iff B7 = 1 and the condition is not `Inactive` (EMCA digest §3.2). CMMO-ST: B7 is
/// reserved 0 and any non-zero condition chains.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Default)]
pub struct Rcb2 {
    /// Bits 0..6.
    pub condition: StepCondition,
    /// B7 (EMCA).
    pub activate: bool,
}

impl Rcb2 {
    /// Decodes PNU 402.
    pub const fn from_byte(b: u8) -> Rcb2 {
        let condition = match b & 0x7F {
            0 => StepCondition::Inactive,
            1 => StepCondition::Mc,
            20 => StepCondition::Position,
            21 => StepCondition::Velocity,
            22 => StepCondition::Force,
            23 => StepCondition::Time,
            c => StepCondition::Invalid(c),
        };
        Rcb2 {
            condition,
            activate: b & 0x80 != 0,
        }
    }
    /// Encodes PNU 402.
    pub const fn to_byte(self) -> u8 {
        let c = match self.condition {
            StepCondition::Inactive => 0,
            StepCondition::Mc => 1,
            StepCondition::Position => 20,
            StepCondition::Velocity => 21,
            StepCondition::Force => 22,
            StepCondition::Time => 23,
            StepCondition::Invalid(c) => c & 0x7F,
        };
        c | ((self.activate as u8) << 7)
    }
    /// Whether the record chains to PNU 416 on `variant` (never on the MTR-DCI).
    pub const fn chains(self, variant: Variant) -> bool {
        let has = !matches!(self.condition, StepCondition::Inactive);
        match variant {
            Variant::MtrDci => false,
            Variant::Emca => has && self.activate,
            Variant::CmmoSt => has,
        }
    }
}

/// PNU 312, comparator status: a bit is 1 while the value is inside its window after the
/// damping time.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Default)]
pub struct ComparatorStatus {
    /// Bit 0: position.
    pub position: bool,
    /// Bit 1: speed.
    pub speed: bool,
    /// Bit 2: force.
    pub force: bool,
    /// Bit 3: time.
    pub time: bool,
}

impl ComparatorStatus {
    /// Decodes PNU 312 (bits 4..7 reserved).
    pub const fn from_byte(b: u8) -> ComparatorStatus {
        ComparatorStatus {
            position: b & 1 != 0,
            speed: b & 2 != 0,
            force: b & 4 != 0,
            time: b & 8 != 0,
        }
    }
    /// Encodes PNU 312.
    pub const fn to_byte(self) -> u8 {
        self.position as u8
            | (self.speed as u8) << 1
            | (self.force as u8) << 2
            | (self.time as u8) << 3
    }
}

use Access::{Ro, Rw, Rw2};
use DataType::{Char, I8, I16, I32, U8, U16, U32};

const U32MAX: i64 = u32::MAX as i64;
const I32MIN: i64 = i32::MIN as i64;
const I32MAX: i64 = i32::MAX as i64;

/// An entry (const constructor keeps the tables one line per parameter).
#[allow(clippy::too_many_arguments)]
const fn p(
    pnu: u16,
    subs: (u8, u8),
    name: &'static str,
    dtype: DataType,
    access: Access,
    default: i64,
    min: i64,
    max: i64,
) -> ParamDef {
    ParamDef {
        pnu,
        first_sub: subs.0,
        last_sub: subs.1,
        name,
        dtype,
        access,
        default,
        min,
        max,
    }
}

/// Read-only entry over the type's whole range.
const fn ro(pnu: u16, subs: (u8, u8), name: &'static str, dtype: DataType) -> ParamDef {
    p(pnu, subs, name, dtype, Ro, 0, dtype.min(), dtype.max())
}

/// Classic simple variable.
const V0: (u8, u8) = (0, 0);
/// EFPC simple variable.
const V1: (u8, u8) = (1, 1);
/// MTR-DCI record arrays: records 0..=31 at IND 1..=32.
const REC32: (u8, u8) = (1, 32);
/// EMCA/CMMO-ST record arrays: records 1..=64.
const REC64: (u8, u8) = (1, 64);

/// MTR-DCI (digest 000 §6.6 Tab. B/7, §5, §8.2). Defaults: size 42, G7, DMES-25.
pub static MTR_DCI: &[ParamDef] = &[
    ro(100, V0, "Manufacturer hardware version", U16),
    ro(101, V0, "Manufacturer firmware version", U16),
    ro(102, V0, "FHPP version", U16),
    ro(114, (1, 12), "Controller serial number", Char),
    ro(120, (1, 30), "Manufacturer device name", Char),
    p(121, (1, 8), "User device name", Char, Rw, 0, 0, 255),
    ro(122, (1, 30), "Drive manufacturer", Char),
    ro(123, (1, 30), "HTTP catalog address", Char),
    ro(124, (1, 30), "Festo order number", Char),
    p(125, V0, "Device control", U8, Rw, 1, 0, 1),
    p(126, (1, 4), "HMI parameters", U8, Rw, 0, 0, 255),
    p(
        127,
        (1, 1),
        "Data memory control: erase EEPROM (16)",
        U8,
        Rw,
        0,
        0,
        16,
    ),
    p(
        127,
        (2, 2),
        "Data memory control: save (1)",
        U8,
        Rw,
        0,
        0,
        1,
    ),
    ro(200, (1, 16), "Diagnostic event", U8),
    ro(201, (1, 16), "Fault number", U16),
    ro(202, (1, 16), "Time stamp", U32),
    p(
        204,
        (1, 1),
        "Diagnostic memory: record incoming+outgoing (1) / incoming (2)",
        U8,
        Rw,
        1,
        1,
        2,
    ),
    p(
        204,
        (2, 2),
        "Diagnostic memory: time stamp 10 ms (1) / 1 ms (2)",
        U8,
        Rw,
        1,
        1,
        2,
    ),
    p(204, (3, 3), "Diagnostic memory: clear (1)", U8, Rw, 0, 0, 1),
    p(
        204,
        (4, 4),
        "Diagnostic memory: number of entries",
        U8,
        Ro,
        0,
        0,
        16,
    ),
    p(
        205,
        V0,
        "Device fault (bit field), write 0 to delete",
        U16,
        Rw,
        0,
        0,
        0,
    ),
    ro(206, (1, 6), "CANopen diagnosis", U8),
    ro(303, V0, "Local digital inputs", U32),
    ro(304, (1, 2), "Local digital outputs", U32),
    ro(305, V0, "Cycle number", U32),
    ro(306, V0, "Keypad status", U8),
    p(400, V0, "Record number", U8, Rw, 0, 0, 31),
    p(
        401,
        REC32,
        "Record control byte 1 (bit 0: relative)",
        U8,
        Rw,
        0,
        0,
        1,
    ),
    p(
        404,
        REC32,
        "Record target position [inc]",
        I32,
        Rw,
        0,
        I32MIN,
        I32MAX,
    ),
    p(
        406,
        REC32,
        "Record velocity [inc/s] (0 = not executable)",
        U32,
        Rw,
        0,
        0,
        100_000,
    ),
    p(
        407,
        REC32,
        "Record acceleration [inc/s²]",
        U32,
        Rw,
        480_000,
        40_000,
        480_000,
    ),
    p(
        500,
        V0,
        "Project zero point offset [inc]",
        I32,
        Rw,
        0,
        I32MIN,
        I32MAX,
    ),
    p(
        501,
        (1, 1),
        "Software end position lower [inc]",
        I32,
        Rw,
        0,
        I32MIN,
        I32MAX,
    ),
    p(
        501,
        (2, 2),
        "Software end position upper [inc] (50 mm)",
        I32,
        Rw,
        270_000,
        I32MIN,
        I32MAX,
    ),
    p(
        502,
        V0,
        "Max velocity [inc/s]",
        U32,
        Rw,
        100_000,
        1,
        100_000,
    ),
    p(
        503,
        V0,
        "Max acceleration [inc/s²]",
        U32,
        Rw,
        480_000,
        40_000,
        480_000,
    ),
    p(
        510,
        V0,
        "Stroke limit, force mode [inc]",
        U32,
        Rw,
        0,
        0,
        U32MAX,
    ),
    p(511, V0, "Min torque [‰]", U16, Rw, 0, 0, 1000),
    p(512, V0, "Max torque [‰]", U16, Rw, 1000, 0, 1000),
    p(520, V0, "Teach target", U8, Rw, 1, 1, 5),
    p(
        531,
        V0,
        "Jog velocity phase 2 [inc/s]",
        I32,
        Rw,
        10_000,
        0,
        100_000,
    ),
    p(
        532,
        V0,
        "Jog acceleration [inc/s²]",
        U32,
        Rw,
        40_000,
        40_000,
        480_000,
    ),
    p(
        534,
        V0,
        "Jog duration phase 1 [ms]",
        U32,
        Rw,
        2000,
        0,
        U32MAX,
    ),
    p(
        541,
        V0,
        "Direct mode acceleration [inc/s²]",
        U32,
        Rw,
        480_000,
        40_000,
        480_000,
    ),
    p(552, V0, "Force target window [‰]", U16, Rw, 100, 0, 1000),
    p(553, V0, "Force damping time [ms]", U16, Rw, 100, 0, 30_000),
    p(
        554,
        V0,
        "Speed limit, force mode [inc/s]",
        U32,
        Rw,
        100_000,
        1,
        U32MAX,
    ),
    p(1000, V0, "Polarity (0 or 0x80)", U8, Rw, 0, 0, 0x80),
    p(
        1001,
        (1, 1),
        "Encoder resolution [lines]",
        U32,
        Ro,
        500,
        0,
        U32MAX,
    ),
    p(
        1001,
        (2, 2),
        "Encoder resolution [revolutions]",
        U32,
        Ro,
        1,
        0,
        U32MAX,
    ),
    p(
        1002,
        (1, 1),
        "Gear ratio numerator (motor)",
        U32,
        Ro,
        27,
        0,
        U32MAX,
    ),
    p(
        1002,
        (2, 2),
        "Gear ratio denominator (shaft)",
        U32,
        Ro,
        4,
        0,
        U32MAX,
    ),
    p(1003, (1, 1), "Feed constant [µm]", U32, Rw, 2500, 1, U32MAX),
    p(
        1003,
        (2, 2),
        "Feed constant [revolutions]",
        U32,
        Rw,
        1,
        1,
        U32MAX,
    ),
    p(
        1004,
        (1, 2),
        "Position factor (num/den)",
        U32,
        Rw,
        1,
        1,
        U32MAX,
    ),
    p(1005, (1, 5), "Axis parameter", U32, Rw, 0, 0, U32MAX),
    p(
        1010,
        V0,
        "Offset axis zero point [inc]",
        I32,
        Rw,
        0,
        I32MIN,
        I32MAX,
    ),
    p(
        1011,
        V0,
        "Homing method (27, 23, -17, -18)",
        I8,
        Rw,
        27,
        -18,
        27,
    ),
    p(
        1012,
        (1, 2),
        "Homing speeds: search, to AZ [inc/s]",
        U32,
        Rw,
        22_400,
        200,
        50_000,
    ),
    p(1014, V0, "Homing required (fixed 1)", U8, Ro, 1, 1, 1),
    p(1015, V0, "Homing max torque [%]", U8, Rw, 150, 0, 200),
    p(1020, V0, "Hold option code (fixed 1)", U16, Ro, 1, 1, 1),
    p(
        1021,
        V0,
        "Fault reaction option code (fixed 2)",
        U16,
        Ro,
        2,
        2,
        2,
    ),
    p(
        1022,
        V0,
        "Target position window [inc]",
        U32,
        Rw,
        750,
        0,
        U32MAX,
    ),
    p(
        1023,
        V0,
        "Position window time [ms]",
        U16,
        Rw,
        100,
        1,
        30_000,
    ),
    p(
        1024,
        (18, 23),
        "Position control parameter set",
        U16,
        Rw,
        0,
        0,
        65_535,
    ),
    p(
        1024,
        (32, 32),
        "Save position (fixed 240: not saved)",
        U16,
        Ro,
        240,
        240,
        240,
    ),
    p(1025, (1, 1), "Motor serial number", U32, Ro, 0, 0, U32MAX),
    p(1025, (3, 3), "I²t time [≈20 ms]", U32, Rw, 100, 1, 32_767),
    ro(1026, (1, 8), "Drive data", U32),
    p(1030, V0, "Motor type (fixed 0)", U16, Ro, 0, 0, 0),
    p(1034, V0, "Max current [‰]", U16, Rw, 1500, 1, 2000),
    p(
        1035,
        V0,
        "Rated motor current [mA]",
        U32,
        Rw,
        2000,
        0,
        U32MAX,
    ),
    p(1036, V0, "Rated motor torque [mNm]", U32, Rw, 0, 0, U32MAX),
    ro(1040, V0, "Position target (demand) value [inc]", I32),
    ro(1041, V0, "Position actual value [inc]", I32),
    p(
        1042,
        V0,
        "Standstill position window [inc] (0 = off)",
        U32,
        Rw,
        750,
        0,
        U32MAX,
    ),
    p(1043, V0, "Standstill timeout [ms]", U16, Rw, 200, 0, 65_535),
];

/// The FHPP PNU family the EMCA and the CMMO-ST share (EMCA digest §3, §4, §6, §7; CMMO-ST
/// digest §4–§6). Access classes are the CMMO-ST's (the EMCA digest lists few).
pub static FHPP_FAMILY: &[ParamDef] = &[
    p(125, V1, "Device control (1 = fieldbus)", U8, Rw, 1, 0, 1),
    p(
        127,
        (1, 4),
        "Data memory control (0x10 factory/restart/load, 1 = save on :2)",
        U8,
        Rw2,
        0,
        0,
        0x10,
    ),
    p(
        128,
        V1,
        "Enable signals (0 = fieldbus only)",
        U8,
        Rw2,
        0,
        0,
        1,
    ),
    ro(200, (1, 200), "Diagnostic event", U8),
    ro(201, (1, 200), "Diagnostic number", U16),
    ro(202, (1, 200), "Time stamp [ms]", U32),
    ro(203, (1, 200), "Additional information", U32),
    p(204, (3, 3), "Diagnostic memory: clear (1)", U8, Rw, 0, 0, 1),
    p(
        204,
        (4, 4),
        "Diagnostic memory: number of entries",
        U8,
        Ro,
        0,
        0,
        200,
    ),
    p(
        205,
        V1,
        "Device fault, highest priority (0xFFFF = none)",
        U16,
        Ro,
        0xFFFF,
        0,
        0xFFFF,
    ),
    ro(220, (1, 32), "Active faults (bitmap)", U32),
    ro(221, (1, 32), "Active warnings (bitmap)", U32),
    p(
        230,
        V1,
        "Fault acknowledgeable (0xFF = no fault)",
        U8,
        Ro,
        0xFF,
        0,
        0xFF,
    ),
    p(280, V1, "Safety state", U8, Ro, 0xFF, 0, 0xFF),
    ro(
        300,
        (1, 3),
        "Position: actual, setpoint, following error [SINC]",
        I32,
    ),
    ro(301, (1, 3), "Force: actual, setpoint, deviation [‰]", I16),
    ro(303, V1, "Local digital inputs", U32),
    ro(304, V1, "Local digital outputs", U32),
    ro(
        310,
        (1, 3),
        "Speed: actual, setpoint, deviation [SINC/s]",
        I32,
    ),
    ro(
        312,
        V1,
        "Comparator status (b0 pos, b1 speed, b2 force, b3 time)",
        U8,
    ),
    ro(320, (1, 2), "FHPP status image", U32),
    ro(321, (1, 2), "FHPP control image", U32),
    p(
        400,
        (1, 1),
        "Setpoint (teach) record number",
        U8,
        Rw,
        1,
        1,
        64,
    ),
    ro(400, (2, 2), "Actual record number", U8),
    p(401, REC64, "RCB1: ABS, COM, REL, XLIM", U8, Rw, 0, 0, 0x37),
    p(
        402,
        REC64,
        "RCB2: step-enabling condition",
        U8,
        Rw,
        0,
        0,
        127,
    ),
    p(
        404,
        REC64,
        "Setpoint value (target position) [SINC]",
        I32,
        Rw,
        0,
        I32MIN,
        I32MAX,
    ),
    p(406, REC64, "Speed [SINC/s]", I32, Rw, 0, 0, I32MAX),
    p(407, REC64, "Acceleration [SINC/s²]", I32, Rw, 0, 0, I32MAX),
    p(408, REC64, "Deceleration [SINC/s²]", I32, Rw, 0, 0, I32MAX),
    p(
        409,
        REC64,
        "Jerk acceleration [(SINC/s³)/10] (0 = max)",
        U32,
        Rw,
        0,
        0,
        U32MAX,
    ),
    p(410, REC64, "Load (additional mass)", U32, Rw, 0, 0, U32MAX),
    p(
        416,
        REC64,
        "Record sequencing target (0 = none)",
        U8,
        Rw,
        0,
        0,
        64,
    ),
    p(
        417,
        REC64,
        "Jerk deceleration [(SINC/s³)/10]",
        U32,
        Rw,
        0,
        0,
        U32MAX,
    ),
    p(
        418,
        REC64,
        "Torque limitation [‰ of PNU 555]",
        I16,
        Rw,
        1000,
        0,
        1000,
    ),
    p(
        421,
        REC64,
        "RCB3: start condition (0 ignore, 1 interrupt, 2 wait)",
        U8,
        Rw,
        0,
        0,
        2,
    ),
    p(
        423,
        REC64,
        "Final speed [SINC/s]",
        I32,
        Rw,
        0,
        I32MIN,
        I32MAX,
    ),
    p(
        424,
        REC64,
        "Max deviation (following error window)",
        I32,
        Rw,
        0,
        0,
        I32MAX,
    ),
    p(425, REC64, "MC with record sequencing", U8, Rw, 0, 0, 1),
    p(426, REC64, "Start delay [ms]", U32, Rw, 0, 0, U32MAX),
    p(
        427,
        REC64,
        "Stroke limit [SINC]",
        I32,
        Rw,
        0,
        I32MIN,
        I32MAX,
    ),
    p(
        428,
        REC64,
        "Torque feed-forward factor",
        U16,
        Rw,
        0,
        0,
        1000,
    ),
    p(
        430,
        REC64,
        "Position comparator min [SINC]",
        I32,
        Rw,
        0,
        I32MIN,
        I32MAX,
    ),
    p(
        431,
        REC64,
        "Position comparator max [SINC]",
        I32,
        Rw,
        0,
        I32MIN,
        I32MAX,
    ),
    p(
        432,
        REC64,
        "Position comparator damping time [ms]",
        U16,
        Rw,
        0,
        0,
        65_535,
    ),
    p(
        433,
        REC64,
        "Speed comparator min [SINC/s]",
        I32,
        Rw,
        0,
        I32MIN,
        I32MAX,
    ),
    p(
        434,
        REC64,
        "Speed comparator max [SINC/s]",
        I32,
        Rw,
        0,
        I32MIN,
        I32MAX,
    ),
    p(
        435,
        REC64,
        "Speed comparator damping time [ms]",
        U16,
        Rw,
        0,
        0,
        65_535,
    ),
    p(
        436,
        REC64,
        "Force comparator min [‰]",
        I16,
        Rw,
        0,
        -1000,
        1000,
    ),
    p(
        437,
        REC64,
        "Force comparator max [‰]",
        I16,
        Rw,
        0,
        -1000,
        1000,
    ),
    p(
        438,
        REC64,
        "Force comparator damping time [ms]",
        U16,
        Rw,
        0,
        0,
        65_535,
    ),
    p(
        439,
        REC64,
        "Time comparator min [ms]",
        U32,
        Rw,
        0,
        0,
        U32MAX,
    ),
    p(
        440,
        REC64,
        "Time comparator max [ms]",
        U32,
        Rw,
        0,
        0,
        U32MAX,
    ),
    p(
        441,
        REC64,
        "Speed setpoint (speed record) [SINC/s]",
        I32,
        Rw,
        0,
        I32MIN,
        I32MAX,
    ),
    p(
        442,
        REC64,
        "Force setpoint (force record) [‰]",
        I16,
        Rw,
        0,
        -1000,
        1000,
    ),
    p(
        500,
        V1,
        "Project zero point offset [SINC]",
        I32,
        Rw,
        0,
        I32MIN,
        I32MAX,
    ),
    p(
        501,
        (1, 2),
        "Software end positions lower/upper [SINC] (0/0 = off)",
        I32,
        Rw2,
        0,
        I32MIN,
        I32MAX,
    ),
    p(502, V1, "Max speed [SINC/s]", I32, Rw2, 0, 0, I32MAX),
    p(
        503,
        V1,
        "Max acceleration [SINC/s²]",
        I32,
        Rw2,
        0,
        0,
        I32MAX,
    ),
    p(
        510,
        V1,
        "Stroke limit, direct force [SINC]",
        I32,
        Rw,
        0,
        I32MIN,
        I32MAX,
    ),
    p(512, V1, "Max current [mA]", I32, Rw2, 0, 0, I32MAX),
    p(520, V1, "Teach target (1..7)", U8, Rw, 1, 1, 7),
    p(
        523,
        (1, 12),
        "Direct-mode setpoint/actual value selection",
        U32,
        Rw,
        0,
        0,
        U32MAX,
    ),
    p(
        524,
        V1,
        "Direct mode: relative to 0 setpoint / 1 actual",
        U8,
        Rw,
        1,
        0,
        1,
    ),
    p(530, V1, "Jog slow speed [SINC/s]", I32, Rw2, 0, 0, I32MAX),
    p(531, V1, "Jog fast speed [SINC/s]", I32, Rw2, 0, 0, I32MAX),
    p(
        532,
        V1,
        "Jog acceleration [SINC/s²]",
        I32,
        Rw2,
        0,
        0,
        I32MAX,
    ),
    p(534, V1, "Jog phase 1 time [ms]", U16, Rw2, 0, 0, 65_535),
    p(
        538,
        V1,
        "Jog following error window",
        I32,
        Rw2,
        0,
        0,
        I32MAX,
    ),
    p(
        539,
        V1,
        "Jog following error delay [ms]",
        U16,
        Rw2,
        0,
        0,
        65_535,
    ),
    p(
        540,
        V1,
        "Direct base speed (100 %) [SINC/s]",
        I32,
        Rw,
        0,
        0,
        I32MAX,
    ),
    p(
        541,
        V1,
        "Direct acceleration [SINC/s²]",
        I32,
        Rw,
        0,
        0,
        I32MAX,
    ),
    p(
        542,
        V1,
        "Direct deceleration [SINC/s²]",
        I32,
        Rw,
        0,
        0,
        I32MAX,
    ),
    p(
        543,
        V1,
        "Direct jerk acceleration [(SINC/s³)/10]",
        U32,
        Rw,
        0,
        0,
        U32MAX,
    ),
    p(544, V1, "Direct load", U32, Rw, 0, 0, U32MAX),
    p(
        547,
        V1,
        "Direct jerk deceleration [(SINC/s³)/10]",
        U32,
        Rw,
        0,
        0,
        U32MAX,
    ),
    p(
        548,
        V1,
        "Direct final speed [SINC/s]",
        I32,
        Rw,
        0,
        I32MIN,
        I32MAX,
    ),
    p(
        549,
        V1,
        "Direct following error window [SINC]",
        I32,
        Rw,
        0,
        0,
        I32MAX,
    ),
    p(552, V1, "Force target window [‰]", I16, Rw2, 0, 0, 1000),
    p(
        555,
        V1,
        "Basic value force (1000 ‰) [mA]",
        U32,
        Rw,
        0,
        0,
        U32MAX,
    ),
    p(
        560,
        V1,
        "Base acceleration, speed mode (100 %) [SINC/s²]",
        I32,
        Rw,
        0,
        0,
        I32MAX,
    ),
    p(
        561,
        V1,
        "Speed target window [SINC/s]",
        I32,
        Rw2,
        0,
        0,
        I32MAX,
    ),
    p(
        566,
        V1,
        "Stroke limit, direct speed [SINC]",
        I32,
        Rw,
        0,
        I32MIN,
        I32MAX,
    ),
    p(
        568,
        V1,
        "Speed deviation window [SINC/s]",
        I32,
        Rw,
        0,
        0,
        I32MAX,
    ),
    p(
        581,
        V1,
        "Direct torque limitation [‰]",
        I16,
        Rw,
        1000,
        0,
        1000,
    ),
    p(582, V1, "Direct start delay [ms]", U32, Rw, 0, 0, U32MAX),
    p(
        583,
        V1,
        "Direct start condition (0 ignore, 1 interrupt, 2 wait)",
        U8,
        Rw,
        0,
        0,
        2,
    ),
    p(
        585,
        V1,
        "Direct position comparator min [SINC]",
        I32,
        Rw,
        0,
        I32MIN,
        I32MAX,
    ),
    p(
        586,
        V1,
        "Direct position comparator max [SINC]",
        I32,
        Rw,
        0,
        I32MIN,
        I32MAX,
    ),
    p(
        587,
        V1,
        "Direct position comparator damping [ms]",
        U16,
        Rw,
        0,
        0,
        65_535,
    ),
    p(
        588,
        V1,
        "Direct speed comparator min [SINC/s]",
        I32,
        Rw,
        0,
        I32MIN,
        I32MAX,
    ),
    p(
        589,
        V1,
        "Direct speed comparator max [SINC/s]",
        I32,
        Rw,
        0,
        I32MIN,
        I32MAX,
    ),
    p(
        590,
        V1,
        "Direct speed comparator damping [ms]",
        U16,
        Rw,
        0,
        0,
        65_535,
    ),
    p(
        591,
        V1,
        "Direct force comparator min [‰]",
        I16,
        Rw,
        0,
        -1000,
        1000,
    ),
    p(
        592,
        V1,
        "Direct force comparator max [‰]",
        I16,
        Rw,
        0,
        -1000,
        1000,
    ),
    p(
        593,
        V1,
        "Direct force comparator damping [ms]",
        U16,
        Rw,
        0,
        0,
        65_535,
    ),
    p(
        594,
        V1,
        "Direct time comparator min [ms]",
        U32,
        Rw,
        0,
        0,
        U32MAX,
    ),
    p(
        595,
        V1,
        "Direct time comparator max [ms]",
        U32,
        Rw,
        0,
        0,
        U32MAX,
    ),
    p(
        600,
        V1,
        "Position exponent (1 SINC = 10^x unit)",
        I8,
        Rw2,
        -7,
        -128,
        127,
    ),
    p(
        601,
        V1,
        "Position unit (0x01 m, 0x41 deg, 0xF0 inch, 0xF6 rev)",
        U8,
        Rw2,
        0x01,
        0,
        255,
    ),
    p(
        1000,
        V1,
        "Reversal of direction (0 or 0x80 = -128)",
        I8,
        Rw2,
        0,
        -128,
        0,
    ),
    p(1002, (1, 2), "Gear ratio num/den", U32, Rw2, 1, 1, U32MAX),
    p(
        1003,
        (1, 2),
        "Feed constant [SINC]/revolutions",
        U32,
        Rw2,
        1,
        1,
        U32MAX,
    ),
    p(1005, (1, 2), "Axis gear num/den", U32, Rw2, 1, 1, U32MAX),
    p(
        1010,
        V1,
        "Offset axis zero point [SINC]",
        I32,
        Rw2,
        0,
        I32MIN,
        I32MAX,
    ),
    p(1011, V1, "Homing method", I8, Rw2, -35, -35, 34),
    p(
        1012,
        (1, 3),
        "Homing speeds: search, to AZ, creep [SINC/s]",
        I32,
        Rw2,
        0,
        0,
        I32MAX,
    ),
    p(
        1013,
        V1,
        "Homing acceleration [SINC/s²]",
        I32,
        Rw2,
        0,
        0,
        I32MAX,
    ),
    p(
        1015,
        V1,
        "Homing stop detection torque [‰]",
        I16,
        Rw2,
        0,
        0,
        1000,
    ),
    p(
        1016,
        V1,
        "Homing stop detection speed limit [SINC/s]",
        I32,
        Rw2,
        0,
        0,
        I32MAX,
    ),
    p(
        1017,
        V1,
        "Homing stop detection damping time [ms]",
        U16,
        Rw2,
        0,
        0,
        65_535,
    ),
    p(
        1022,
        V1,
        "Target position window [SINC]",
        I32,
        Rw2,
        0,
        0,
        I32MAX,
    ),
    p(1023, V1, "Target damping time [ms]", U16, Rw2, 0, 0, 65_535),
    p(
        1029,
        V1,
        "Quick-stop deceleration [SINC/s²]",
        I32,
        Rw2,
        0,
        0,
        I32MAX,
    ),
    ro(1040, V1, "Setpoint position [SINC]", I32),
    ro(1041, V1, "Actual position [SINC]", I32),
    p(
        1042,
        V1,
        "Standstill window [SINC] (0 = off)",
        I32,
        Rw2,
        0,
        0,
        I32MAX,
    ),
    p(1043, V1, "Standstill time [ms]", U16, Rw2, 0, 0, 65_535),
    p(
        1045,
        V1,
        "Following error delay time [ms]",
        U16,
        Rw2,
        0,
        0,
        65_535,
    ),
];

/// EMCA-only entries and EMCA values of shared PNUs (searched before [`FHPP_FAMILY`]).
pub static EMCA: &[ParamDef] = &[
    // Digest 002 §6: 1 major, 2 minor, 3 revision, 4 build; the type is not given (one
    // number each: u8 here), nor the simulated firmware's numbers (0).
    ro(
        100,
        (1, 4),
        "Firmware version (major, minor, revision, build)",
        U8,
    ),
    p(
        40,
        (1, 10),
        "FHPP+ receive telegram (PNU list)",
        U32,
        Rw2,
        0,
        0,
        U32MAX,
    ),
    p(
        41,
        (1, 10),
        "FHPP+ response telegram (PNU list)",
        U32,
        Rw2,
        0,
        0,
        U32MAX,
    ),
    ro(42, V1, "FHPP+ receive telegram status", U32),
    ro(43, V1, "FHPP+ response telegram status", U32),
    ro(350, V1, "Sample position, rising edge [SINC]", I32),
    ro(351, V1, "Sample position, falling edge [SINC]", I32),
    p(352, V1, "Sample mode (0 = off)", U8, Rw, 0, 0, 255),
    // B7 = "activate record sequencing" (EMCA only).
    p(
        402,
        REC64,
        "RCB2: step-enabling condition, B7 activate sequencing",
        U8,
        Rw,
        0,
        0,
        255,
    ),
    p(
        1001,
        (1, 1),
        "Encoder resolution [increments]",
        U32,
        Ro,
        4096,
        0,
        U32MAX,
    ),
    p(
        1001,
        (2, 2),
        "Encoder resolution [motor revolutions]",
        U32,
        Ro,
        1,
        0,
        U32MAX,
    ),
];

/// CMMO-ST-only entries and CMMO-ST values of shared PNUs (searched before [`FHPP_FAMILY`]).
pub static CMMO_ST: &[ParamDef] = &[
    ro(101, (1, 4), "Firmware version", U16),
    p(
        1001,
        (1, 1),
        "Encoder resolution [increments]",
        U32,
        Ro,
        2000,
        0,
        U32MAX,
    ),
    p(
        1001,
        (2, 2),
        "Encoder resolution [motor revolutions]",
        U32,
        Ro,
        1,
        0,
        U32MAX,
    ),
];

#[cfg(test)]
mod tests {
    use super::*;
    use crate::fhpp::fpc::Value;

    const ALL: [Variant; 3] = [Variant::MtrDci, Variant::Emca, Variant::CmmoSt];

    #[test]
    fn tables_are_well_formed() {
        for v in ALL {
            let t = Table::of(v);
            for d in t.entries() {
                assert!(d.first_sub <= d.last_sub, "{v:?} {}", d.pnu);
                assert!(
                    d.dtype.min() <= d.min && d.min <= d.max && d.max <= d.dtype.max(),
                    "{v:?} {}",
                    d.pnu
                );
                assert!(
                    d.min <= d.default && d.default <= d.max,
                    "{v:?} {}: default",
                    d.pnu
                );
                if v == Variant::MtrDci {
                    assert!(d.pnu <= 2047, "classic PNU has 11 bits");
                }
            }
            // No two entries of one list overlap.
            for list in [t.specific, t.common] {
                for (i, a) in list.iter().enumerate() {
                    for b in &list[i + 1..] {
                        let overlap = a.pnu == b.pnu
                            && a.first_sub <= b.last_sub
                            && b.first_sub <= a.last_sub;
                        assert!(!overlap, "{v:?}: PNU {} twice", a.pnu);
                    }
                }
            }
        }
    }

    #[test]
    fn the_pnus_simulators_and_coordinator_need_exist() {
        let records = [401u16, 404, 406, 407];
        let homing = [1010u16, 1011, 1012];
        let common = [
            125u16, 400, 500, 501, 520, 1022, 1023, 1042, 1043, 200, 201, 202, 204,
        ];
        for v in ALL {
            let t = Table::of(v);
            let rec = record_subindex(v, v.max_record()).unwrap();
            for pnu in records {
                assert!(t.lookup(Param::new(pnu, rec)).is_ok(), "{v:?} {pnu}");
            }
            for pnu in homing.iter().chain(&common) {
                assert!(t.entries().any(|d| d.pnu == *pnu), "{v:?} {pnu}");
            }
        }
        let emca = Table::of(Variant::Emca);
        for pnu in [
            402u16, 416, 423, 425, 426, 312, 350, 351, 352, 583, 540, 555, 560,
        ] {
            assert!(emca.entries().any(|d| d.pnu == pnu), "EMCA {pnu}");
        }
        for pnu in 430u16..=440 {
            assert!(emca.lookup(Param::new(pnu, 64)).is_ok(), "{pnu}");
        }
        for pnu in 585u16..=595 {
            assert!(emca.lookup(Param::new(pnu, 1)).is_ok(), "{pnu}");
        }
        let cmmo = Table::of(Variant::CmmoSt);
        assert_eq!(
            cmmo.lookup(Param::new(350, 1)),
            Err(ParamError::NoSuchPnu { pnu: 350 })
        );
        let mtr = Table::of(Variant::MtrDci);
        assert!(mtr.lookup(Param::new(541, 0)).is_ok() && mtr.lookup(Param::new(534, 0)).is_ok());
        assert_eq!(
            mtr.lookup(Param::new(402, 1)),
            Err(ParamError::NoSuchPnu { pnu: 402 })
        );
    }

    #[test]
    fn lookup_distinguishes_pnu_and_subindex_errors() {
        let mtr = Table::of(Variant::MtrDci);
        assert_eq!(
            mtr.lookup(Param::new(404, 33)),
            Err(ParamError::BadSubindex { pnu: 404, sub: 33 })
        );
        assert_eq!(
            mtr.lookup(Param::new(404, 33))
                .unwrap_err()
                .fpc_number(Variant::MtrDci),
            3
        );
        assert_eq!(
            mtr.lookup(Param::new(9, 0))
                .unwrap_err()
                .fpc_number(Variant::MtrDci),
            0
        );
        assert_eq!(
            mtr.lookup(Param::new(1022, 1)),
            Err(ParamError::BadSubindex { pnu: 1022, sub: 1 })
        );
        assert_eq!(mtr.lookup(Param::new(204, 4)).unwrap().access, Access::Ro);
        let cmmo = Table::of(Variant::CmmoSt);
        // Simple variable: sub-index 1 (0 accepted).
        assert_eq!(cmmo.lookup(Param::new(1022, 1)).unwrap().pnu, 1022);
        assert_eq!(cmmo.lookup(Param::new(1022, 0)).unwrap().pnu, 1022);
        assert!(cmmo.lookup(Param::new(1022, 2)).is_err());
        assert_eq!(cmmo.lookup(Param::new(1001, 1)).unwrap().default, 2000);
        assert_eq!(
            Table::of(Variant::Emca)
                .lookup(Param::new(1001, 1))
                .unwrap()
                .default,
            4096
        );
    }

    #[test]
    fn write_checks_give_the_device_error_numbers() {
        let mtr = Table::of(Variant::MtrDci);
        // Record 5's velocity above the size-42 maximum.
        let sub = record_subindex(Variant::MtrDci, 5).unwrap();
        assert_eq!(sub, 6);
        let e = mtr
            .check_write(Param::new(406, sub), Value::Dword(100_001), true)
            .unwrap_err();
        assert_eq!(
            e,
            ParamError::OutOfRange {
                pnu: 406,
                sub: 6,
                value: 100_001,
                min: 0,
                max: 100_000
            }
        );
        assert_eq!(e.fpc_number(Variant::MtrDci), 22);
        assert_eq!(
            mtr.check_write(Param::new(406, sub), Value::Dword(50_000), true)
                .map(|x| x.1),
            Ok(50_000)
        );
        // Classic: the ReqID width must match the type.
        let e = mtr
            .check_write(Param::new(406, sub), Value::Word(5), true)
            .unwrap_err();
        assert_eq!(e.fpc_number(Variant::MtrDci), 5);
        // Read-only.
        let e = mtr
            .check_write(Param::new(1041, 0), Value::Dword(0), false)
            .unwrap_err();
        assert_eq!(e.fpc_number(Variant::MtrDci), 1);
        // Signed int8 homing method −17 as a byte 0xEF.
        assert_eq!(
            mtr.check_write(Param::new(1011, 0), Value::Byte(0xEF), true)
                .map(|x| x.1),
            Ok(-17)
        );

        let cmmo = Table::of(Variant::CmmoSt);
        let e = cmmo
            .check_write(Param::new(421, 3), Value::Dword(3), true)
            .unwrap_err();
        assert_eq!(e.fpc_number(Variant::CmmoSt), 0x02);
        // rw2 with the output stage on: 0x11; off: accepted.
        let e = cmmo
            .check_write(Param::new(1022, 1), Value::Dword(10), true)
            .unwrap_err();
        assert_eq!(e.fpc_number(Variant::CmmoSt), 0x11);
        assert!(
            cmmo.check_write(Param::new(1022, 1), Value::Dword(10), false)
                .is_ok()
        );
        // EFPC values are 32-bit two's complement: −1000 ‰.
        let neg = DataType::I16.encode(-1000, Channel::Enhanced);
        assert_eq!(neg, Value::Dword(0xFFFF_FC18));
        assert_eq!(
            cmmo.check_write(Param::new(436, 1), neg, true).map(|x| x.1),
            Ok(-1000)
        );
        // RCB2 bit 7 is allowed on the EMCA only.
        assert!(
            cmmo.check_write(Param::new(402, 1), Value::Dword(0x81), true)
                .is_err()
        );
        assert!(
            Table::of(Variant::Emca)
                .check_write(Param::new(402, 1), Value::Dword(0x81), true)
                .is_ok()
        );
        assert_eq!(
            Table::of(Variant::Emca)
                .check_read(Param::new(350, 1))
                .unwrap()
                .access,
            Access::Ro
        );
    }

    #[test]
    fn record_subindices_and_sdo_addresses() {
        assert_eq!(record_subindex(Variant::MtrDci, 0), Some(1));
        assert_eq!(record_subindex(Variant::MtrDci, 31), Some(32));
        assert_eq!(record_subindex(Variant::MtrDci, 32), None);
        assert_eq!(record_subindex(Variant::Emca, 0), None);
        assert_eq!(record_subindex(Variant::Emca, 64), Some(64));
        assert_eq!(record_subindex(Variant::CmmoSt, 65), None);
        let mtr = Table::of(Variant::MtrDci);
        // 2000h + PNU: 401 → 2191h, 1043 → 2413h, 1023 → 23FFh (digest E17).
        assert_eq!(
            mtr.lookup(Param::new(401, 1)).unwrap().sdo_address(1),
            Address::new(0x2191, 1)
        );
        assert_eq!(
            mtr.lookup(Param::new(1043, 0)).unwrap().sdo_address(0),
            Address::new(0x2413, 0)
        );
        assert_eq!(
            mtr.lookup(Param::new(1023, 0)).unwrap().sdo_address(0),
            Address::new(0x23FF, 0)
        );
    }

    #[test]
    fn record_control_bytes() {
        // EMCA/CMMO-ST: relative, force, relative to actual, stroke monitoring off.
        let r = Rcb1 {
            relative: true,
            com: ControlMode::Force,
            rel_to_actual: true,
            xlim_off: true,
        };
        assert_eq!(r.to_byte(Variant::Emca), 0b0011_0011);
        assert_eq!(Rcb1::from_byte(0b0011_0011, Variant::CmmoSt), r);
        assert_eq!(
            Rcb1::from_byte(0b0000_0110, Variant::Emca).com,
            ControlMode::Reserved
        );
        // MTR-DCI: bit 0 only.
        assert_eq!(
            Rcb1::from_byte(0xFF, Variant::MtrDci),
            Rcb1 {
                relative: true,
                ..Rcb1::default()
            }
        );
        assert_eq!(r.to_byte(Variant::MtrDci), 1);
        for b in 0..=255u8 {
            assert_eq!(Rcb2::from_byte(b).to_byte(), b);
            assert_eq!(ComparatorStatus::from_byte(b).to_byte(), b & 0x0F);
        }
        let mc = Rcb2::from_byte(1);
        assert_eq!(mc.condition, StepCondition::Mc);
        assert!(
            mc.chains(Variant::CmmoSt) && !mc.chains(Variant::Emca) && !mc.chains(Variant::MtrDci)
        );
        let emca = Rcb2::from_byte(0x80 | 20);
        assert_eq!(emca.condition, StepCondition::Position);
        assert!(emca.chains(Variant::Emca));
        assert!(!Rcb2::from_byte(0x80).chains(Variant::Emca));
        assert_eq!(Rcb2::from_byte(5).condition, StepCondition::Invalid(5));
    }

    #[test]
    fn store_behind_the_fpc_server() {
        use crate::fhpp::ByteOrder;
        use crate::fhpp::fpc::{Codec, Request, Response, Server};
        assert!(ParamStore::<16>::new(Variant::MtrDci).is_err());
        let needed = Table::of(Variant::MtrDci).value_count();
        let mut mtr = ParamStore::<512>::new(Variant::MtrDci).unwrap();
        assert!(needed <= 512);
        assert_eq!(mtr.get(Param::new(1022, 0)), Ok(750));
        assert_eq!(mtr.get(Param::new(407, 32)), Ok(480_000));
        let codec = Codec::new(Channel::Classic, ByteOrder::Little);
        let mut server = Server::new(codec);
        let sub = record_subindex(Variant::MtrDci, 5).unwrap();
        let w = codec.encode_request(Request::Write(Param::new(406, sub), Value::Dword(200_000)));
        let r = codec.decode_response(&server.handle(&w, &mut mtr));
        assert_eq!(r, Ok(Response::Error(Param::new(406, sub), 22)));
        let w = codec.encode_request(Request::Write(Param::new(406, sub), Value::Dword(40_000)));
        let r = codec.decode_response(&server.handle(&w, &mut mtr));
        assert_eq!(
            r,
            Ok(Response::Value(Param::new(406, sub), Value::Dword(40_000)))
        );
        assert_eq!(mtr.get(Param::new(406, sub)), Ok(40_000));
        assert_eq!(mtr.get(Param::new(406, sub + 1)), Ok(0));
        let rd = codec.encode_request(Request::Read(Param::new(1011, 0)));
        let r = codec.decode_response(&server.handle(&rd, &mut mtr));
        assert_eq!(r, Ok(Response::Value(Param::new(1011, 0), Value::Byte(27))));
        // No device control: classic error 11.
        mtr.fieldbus_control = false;
        let w = codec.encode_request(Request::Write(Param::new(1022, 0), Value::Dword(100)));
        let r = codec.decode_response(&server.handle(&w, &mut mtr));
        assert_eq!(r, Ok(Response::Error(Param::new(1022, 0), 11)));

        assert!(Table::of(Variant::Emca).value_count() <= 4096);
        let mut cmmo = ParamStore::<4096>::new(Variant::CmmoSt).unwrap();
        cmmo.stage_on = true;
        let codec = Codec::new(Channel::Enhanced, ByteOrder::Big);
        let mut server = Server::new(codec);
        let w = codec.encode_request(Request::Write(Param::new(1022, 1), Value::Dword(500)));
        let r = codec.decode_response(&server.handle(&w, &mut cmmo));
        assert_eq!(r, Ok(Response::Error(Param::new(1022, 1), 0x11)));
        cmmo.set(Param::new(1041, 1), -1234).unwrap();
        let rd = codec.encode_request(Request::Read(Param::new(1041, 1)));
        let r = codec.decode_response(&server.handle(&rd, &mut cmmo));
        assert_eq!(
            r,
            Ok(Response::Value(
                Param::new(1041, 1),
                Value::Dword(-1234i32 as u32)
            ))
        );
        assert_eq!(cmmo.get(Param::new(1001, 1)), Ok(2000));
        cmmo.reset_defaults();
        assert_eq!(cmmo.get(Param::new(1041, 1)), Ok(0));
    }

    #[test]
    fn encode_decode_per_type() {
        for (t, v) in [
            (I8, -18i64),
            (U8, 200),
            (I16, -1000),
            (U16, 60_000),
            (I32, -5),
            (U32, 4_000_000_000),
        ] {
            for ch in [Channel::Classic, Channel::Enhanced] {
                assert_eq!(t.decode(t.encode(v, ch)), v, "{t:?} {ch:?}");
            }
        }
        assert_eq!(I8.encode(-18, Channel::Classic), Value::Byte(0xEE));
        assert_eq!(U16.encode(100, Channel::Classic), Value::Word(100));
    }
}
