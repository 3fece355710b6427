//! EDS and DCF import (CiA 306): the INI text of a device description, turned into the entry
//! definitions of an [`ObjectDictionary`]. Std only: it runs at start-up or in tools, never in
//! the cycle.
//!
//! Understood: object sections `[1000]` and sub-index sections `[1018sub2]`, `ObjectType`
//! (VAR, ARRAY, RECORD, DOMAIN; DEFTYPE/DEFSTRUCT are skipped), `SubNumber` (checked against
//! the sub sections present), `CompactSubObj` with the optional `[xxxxName]` and
//! `[xxxxValue]` sections, `DataType` (hex codes), `AccessType` (ro, wo, rw, rwr, rww, const),
//! `DefaultValue`, `ParameterValue` (a DCF's configured value, which wins over the default),
//! `LowLimit`/`HighLimit`, `PDOMapping`, and numbers in hex (`0x`), octal (leading `0`) or
//! decimal, with `$NODEID` terms (`$NODEID+0x180`, `0x200+$NODEID`) resolved against the node-ID
//! the caller supplies (or a DCF's `[DeviceComissioning] NodeID`).
//!
//! ```
//! use drivers::canopen::{Address, NodeId};
//! use drivers::canopen::eds::Eds;
//! use drivers::canopen::od::ObjectDictionary;
//! let text = "[1000]\nParameterName=Device type\nDataType=0x0007\nAccessType=ro\nDefaultValue=0x00020192\n\
//!             [1800]\nParameterName=TPDO1\nObjectType=0x9\nSubNumber=2\n\
//!             [1800sub0]\nParameterName=count\nDataType=0x0005\nAccessType=ro\nDefaultValue=1\n\
//!             [1800sub1]\nParameterName=COB-ID\nDataType=0x0007\nAccessType=rw\nDefaultValue=$NODEID+0x180\n";
//! let eds = Eds::parse(text, NodeId::new(5)).unwrap();
//! let mut od: ObjectDictionary<'_, 8, 64> = ObjectDictionary::new();
//! eds.load_into(&mut od).unwrap();
//! assert_eq!(od.get_u32(Address::new(0x1800, 1)), Ok(0x185));
//! ```

use std::collections::BTreeMap;
use std::string::String;
use std::vec::Vec;

use super::od::{
    AccessType, DataType, EntryDef, ObjectDictionary, OdError, TypeClass, Value, encode_value,
};
use super::{AbortCode, Address, NodeId};

/// Bytes reserved for a writable string or DOMAIN entry whose default is shorter.
pub const DEFAULT_STRING_CAPACITY: usize = 32;

/// Why an EDS/DCF text was refused. Every variant names the line (1-based) and, where there is
/// one, the key.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum EdsError {
    /// A line that is not a section header, a `key=value` pair or a `;` comment.
    #[error("line {line}: {text:?} is neither [section], key=value nor a ;comment")]
    Syntax {
        /// The line.
        line: usize,
        /// Its text.
        text: String,
    },
    /// A key before the first section.
    #[error("line {line}: key {key} comes before any [section]")]
    KeyOutsideSection {
        /// The line.
        line: usize,
        /// The key.
        key: String,
    },
    /// The same section twice.
    #[error("line {line}: section [{section}] appears a second time")]
    DuplicateSection {
        /// The line of the second header.
        line: usize,
        /// The section name.
        section: String,
    },
    /// A required key is missing.
    #[error("line {line}: section [{section}] lacks {key}")]
    MissingKey {
        /// The line of the section header.
        line: usize,
        /// The section name.
        section: String,
        /// The key.
        key: &'static str,
    },
    /// A value that should be a number is not.
    #[error("line {line}: {key}={value:?} is not a number")]
    BadNumber {
        /// The line.
        line: usize,
        /// The key.
        key: String,
        /// The text.
        value: String,
    },
    /// `$NODEID` used, but no node-ID was given and the file has none.
    #[error("line {line}: {key}={value:?} uses $NODEID but no node-ID is known")]
    NodeIdRequired {
        /// The line.
        line: usize,
        /// The key.
        key: String,
        /// The text.
        value: String,
    },
    /// A `DataType` this stack does not model.
    #[error("line {line}: DataType={value} is not a data type this stack models")]
    UnknownDataType {
        /// The line.
        line: usize,
        /// The text.
        value: String,
    },
    /// An `AccessType` other than ro, wo, rw, rwr, rww, const.
    #[error("line {line}: AccessType={value:?} is not ro, wo, rw, rwr, rww or const")]
    UnknownAccessType {
        /// The line.
        line: usize,
        /// The text.
        value: String,
    },
    /// An `ObjectType` other than 2 (DOMAIN), 5, 6 (skipped), 7 (VAR), 8 (ARRAY), 9 (RECORD).
    #[error("line {line}: ObjectType={value} is not 2, 5, 6, 7, 8 or 9")]
    UnknownObjectType {
        /// The line.
        line: usize,
        /// The value.
        value: u64,
    },
    /// A value that does not fit the entry's data type.
    #[error("line {line}: {key}={value:?} does not fit {data_type:?}: {code}")]
    ValueOutOfRange {
        /// The line.
        line: usize,
        /// The key.
        key: String,
        /// The text.
        value: String,
        /// The entry's type.
        data_type: DataType,
        /// The abort code a write of the value would get.
        code: AbortCode,
    },
    /// `SubNumber` disagrees with the sub-index sections present.
    #[error(
        "line {line}: [{section}] declares SubNumber={declared} but has {found} sub-index sections"
    )]
    SubNumber {
        /// The line of the object section.
        line: usize,
        /// The section name.
        section: String,
        /// `SubNumber`.
        declared: u64,
        /// Sub sections found.
        found: usize,
    },
    /// A sub-index section whose object section is missing.
    #[error("line {line}: [{section}] has no object section [{index:04X}]")]
    OrphanSub {
        /// The line.
        line: usize,
        /// The section name.
        section: String,
        /// The missing object's index.
        index: u16,
    },
    /// The dictionary refused an entry while loading.
    #[error("line {line}: {addr} could not be loaded: {source}")]
    Load {
        /// The line of the entry's section.
        line: usize,
        /// The entry.
        addr: Address,
        /// Why.
        source: OdError,
    },
}

/// A value parsed from the file.
#[derive(Debug, Clone, PartialEq)]
pub enum EdsValue {
    /// An unsigned integer or BOOLEAN.
    Unsigned(u64),
    /// A signed integer.
    Signed(i64),
    /// REAL32.
    Real32(f32),
    /// REAL64.
    Real64(f64),
    /// Strings, DOMAIN, TIME types.
    Bytes(Vec<u8>),
}

impl EdsValue {
    /// The borrowed form the dictionary takes.
    pub fn as_value(&self) -> Value<'_> {
        match self {
            EdsValue::Unsigned(v) => Value::Unsigned(*v),
            EdsValue::Signed(v) => Value::Signed(*v),
            EdsValue::Real32(v) => Value::Real32(*v),
            EdsValue::Real64(v) => Value::Real64(*v),
            EdsValue::Bytes(b) => Value::Bytes(b),
        }
    }
}

/// One entry (sub-index) as the file describes it.
#[derive(Debug, Clone, PartialEq)]
pub struct EdsEntry {
    /// Index and sub-index.
    pub addr: Address,
    /// `ParameterName`.
    pub name: String,
    /// `DataType`.
    pub data_type: DataType,
    /// `AccessType`.
    pub access: AccessType,
    /// `PDOMapping`.
    pub pdo_mappable: bool,
    /// `DefaultValue` (zero or empty when absent).
    pub default: EdsValue,
    /// `ParameterValue` of a DCF.
    pub parameter_value: Option<EdsValue>,
    /// `LowLimit`.
    pub low: Option<EdsValue>,
    /// `HighLimit`.
    pub high: Option<EdsValue>,
    /// The line of the section that defines it.
    pub line: usize,
}

impl EdsEntry {
    /// The value the dictionary starts with: the DCF's `ParameterValue`, else the default.
    pub fn value(&self) -> &EdsValue {
        self.parameter_value.as_ref().unwrap_or(&self.default)
    }

    /// The definition for an [`ObjectDictionary`], borrowing names and bytes from `self`.
    pub fn to_def(&self) -> EntryDef<'_> {
        let mut d = EntryDef::new(self.addr, &self.name, self.data_type, self.access)
            .default_value(self.value().as_value());
        d.pdo_mappable = self.pdo_mappable;
        d.low = self.low.as_ref().map(EdsValue::as_value);
        d.high = self.high.as_ref().map(EdsValue::as_value);
        if self.data_type.size().is_none() {
            let len = match self.value() {
                EdsValue::Bytes(b) => b.len(),
                _ => 0,
            };
            d.capacity = if self.access.writable() {
                len.max(DEFAULT_STRING_CAPACITY)
            } else {
                len
            };
        }
        d
    }
}

/// A parsed EDS or DCF.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct Eds {
    /// `[FileInfo]` keys (lower-case) and values.
    pub file_info: BTreeMap<String, String>,
    /// `[DeviceInfo]` keys (lower-case) and values.
    pub device_info: BTreeMap<String, String>,
    /// The node-ID `$NODEID` was resolved against, if any.
    pub node_id: Option<u8>,
    /// Every entry, in address order.
    pub entries: Vec<EdsEntry>,
}

struct Section {
    name: String,
    line: usize,
    keys: Vec<(String, String, usize)>,
}

impl Section {
    fn get(&self, key: &str) -> Option<(&str, usize)> {
        self.keys
            .iter()
            .find(|(k, _, _)| k == key)
            .map(|(_, v, l)| (v.as_str(), *l))
    }
}

enum SectionKind {
    Object(u16),
    Sub(u16, u8),
    Other,
}

fn section_kind(name: &str) -> SectionKind {
    let hex4 = |s: &str| {
        (!s.is_empty() && s.len() <= 4 && s.chars().all(|c| c.is_ascii_hexdigit()))
            .then(|| u16::from_str_radix(s, 16).ok())
            .flatten()
    };
    if let Some(i) = hex4(name) {
        return SectionKind::Object(i);
    }
    if let Some(pos) = name.find("SUB")
        && let Some(i) = hex4(&name[..pos])
    {
        let sub = &name[pos + 3..];
        if !sub.is_empty()
            && sub.len() <= 2
            && let Ok(s) = u8::from_str_radix(sub, 16)
        {
            return SectionKind::Sub(i, s);
        }
    }
    SectionKind::Other
}

fn split_sections(text: &str) -> Result<Vec<Section>, EdsError> {
    let mut sections: Vec<Section> = Vec::new();
    let mut seen: BTreeMap<String, ()> = BTreeMap::new();
    for (i, raw) in text.lines().enumerate() {
        let line = i + 1;
        let l = raw.trim();
        if l.is_empty() || l.starts_with(';') {
            continue;
        }
        if let Some(rest) = l.strip_prefix('[') {
            let name = rest
                .strip_suffix(']')
                .ok_or_else(|| EdsError::Syntax {
                    line,
                    text: l.into(),
                })?
                .trim()
                .to_ascii_uppercase();
            if seen.insert(name.clone(), ()).is_some() {
                return Err(EdsError::DuplicateSection {
                    line,
                    section: name,
                });
            }
            sections.push(Section {
                name,
                line,
                keys: Vec::new(),
            });
            continue;
        }
        let (k, v) = l.split_once('=').ok_or_else(|| EdsError::Syntax {
            line,
            text: l.into(),
        })?;
        let key = k.trim().to_ascii_lowercase();
        let s = sections
            .last_mut()
            .ok_or_else(|| EdsError::KeyOutsideSection {
                line,
                key: key.clone(),
            })?;
        s.keys.push((key, v.trim().to_string(), line));
    }
    Ok(sections)
}

/// Parses one number term: `0x..` hex, leading-`0` octal, decimal.
fn parse_term(t: &str) -> Option<i128> {
    let t = t.trim();
    let (neg, t) = match t.strip_prefix('-') {
        Some(r) => (true, r.trim()),
        None => (false, t),
    };
    let v = if let Some(h) = t.strip_prefix("0x").or_else(|| t.strip_prefix("0X")) {
        i128::from_str_radix(h, 16).ok()?
    } else if t.len() > 1 && t.starts_with('0') {
        i128::from_str_radix(&t[1..], 8).ok()?
    } else {
        t.parse::<i128>().ok()?
    };
    Some(if neg { -v } else { v })
}

/// Context for error messages while converting one key's value.
struct Ctx<'a> {
    line: usize,
    key: &'a str,
    value: &'a str,
}

impl Ctx<'_> {
    fn bad_number(&self) -> EdsError {
        EdsError::BadNumber {
            line: self.line,
            key: self.key.into(),
            value: self.value.into(),
        }
    }
}

/// An integer expression: terms joined by `+`, each a number or `$NODEID`.
fn parse_int(c: &Ctx<'_>, node: Option<u8>) -> Result<i128, EdsError> {
    let mut sum = 0i128;
    let text = c.value.trim();
    if text.is_empty() {
        return Err(c.bad_number());
    }
    for term in text.split('+') {
        let term = term.trim();
        if term.eq_ignore_ascii_case("$NODEID") {
            let n = node.ok_or_else(|| EdsError::NodeIdRequired {
                line: c.line,
                key: c.key.into(),
                value: c.value.into(),
            })?;
            sum += n as i128;
        } else {
            sum += parse_term(term).ok_or_else(|| c.bad_number())?;
        }
    }
    Ok(sum)
}

/// A value of `dt` from its text.
fn parse_value(c: &Ctx<'_>, dt: DataType, node: Option<u8>) -> Result<EdsValue, EdsError> {
    let out_of_range = |code| EdsError::ValueOutOfRange {
        line: c.line,
        key: c.key.into(),
        value: c.value.into(),
        data_type: dt,
        code,
    };
    let v = match dt.class() {
        TypeClass::Bytes => match dt {
            DataType::OctetString => {
                let hex: String = c.value.chars().filter(|ch| !ch.is_whitespace()).collect();
                // Checked first so the byte slicing below stays on character boundaries.
                if !hex.chars().all(|ch| ch.is_ascii_hexdigit()) || !hex.len().is_multiple_of(2) {
                    return Err(c.bad_number());
                }
                let bytes = (0..hex.len())
                    .step_by(2)
                    .map(|i| u8::from_str_radix(&hex[i..i + 2], 16))
                    .collect::<Result<Vec<u8>, _>>()
                    .map_err(|_| c.bad_number())?;
                EdsValue::Bytes(bytes)
            }
            DataType::TimeOfDay | DataType::TimeDifference => EdsValue::Bytes(vec![0; 6]),
            // A DOMAIN's default is often a file name, not its content.
            DataType::Domain => EdsValue::Bytes(Vec::new()),
            _ => EdsValue::Bytes(c.value.as_bytes().to_vec()),
        },
        TypeClass::Real => {
            let f: f64 = c.value.trim().parse().map_err(|_| c.bad_number())?;
            if dt == DataType::Real32 {
                EdsValue::Real32(f as f32)
            } else {
                EdsValue::Real64(f)
            }
        }
        TypeClass::Unsigned => {
            let v = parse_int(c, node)?;
            if v < 0 {
                return Err(out_of_range(AbortCode::ValueTooLow));
            }
            EdsValue::Unsigned(u64::try_from(v).map_err(|_| out_of_range(AbortCode::ValueTooHigh))?)
        }
        TypeClass::Signed => {
            let mut v = parse_int(c, node)?;
            let bits = dt.size().unwrap_or(8) as u32 * 8;
            let max = (1i128 << (bits - 1)) - 1;
            // Files often write signed limits in hex as their bit pattern (0x80000000 for
            // INTEGER32's minimum): read such a pattern as two's complement.
            let hex = c.value.trim().to_ascii_lowercase().starts_with("0x");
            if hex && v > max && v < (1i128 << bits) {
                v -= 1i128 << bits;
            }
            EdsValue::Signed(i64::try_from(v).map_err(|_| out_of_range(AbortCode::ValueTooHigh))?)
        }
    };
    // The dictionary's own range check, so a file cannot hold what a write could not.
    let mut buf = vec![
        0u8;
        8.max(match &v {
            EdsValue::Bytes(b) => b.len(),
            _ => 0,
        })
    ];
    encode_value(dt, &v.as_value(), &mut buf).map_err(out_of_range)?;
    Ok(v)
}

fn parse_access(value: &str, line: usize) -> Result<AccessType, EdsError> {
    Ok(match value.trim().to_ascii_lowercase().as_str() {
        "ro" => AccessType::Ro,
        "wo" => AccessType::Wo,
        "rw" => AccessType::Rw,
        "rwr" => AccessType::Rwr,
        "rww" => AccessType::Rww,
        "const" => AccessType::Const,
        _ => {
            return Err(EdsError::UnknownAccessType {
                line,
                value: value.into(),
            });
        }
    })
}

/// The keys an entry needs, possibly inherited from a compact object's section.
struct EntryKeys<'a> {
    section: &'a Section,
    /// A DOMAIN object (ObjectType 2) may leave out its DataType.
    domain: bool,
}

impl<'a> EntryKeys<'a> {
    fn required(&self, key: &'static str) -> Result<(&'a str, usize), EdsError> {
        self.section.get(key).ok_or_else(|| EdsError::MissingKey {
            line: self.section.line,
            section: self.section.name.clone(),
            key: match key {
                "parametername" => "ParameterName",
                "datatype" => "DataType",
                "accesstype" => "AccessType",
                _ => key,
            },
        })
    }

    fn data_type(&self, node: Option<u8>) -> Result<DataType, EdsError> {
        if self.domain && self.section.get("datatype").is_none() {
            return Ok(DataType::Domain);
        }
        let (v, line) = self.required("datatype")?;
        let c = Ctx {
            line,
            key: "DataType",
            value: v,
        };
        let code = parse_int(&c, node)?;
        u16::try_from(code)
            .ok()
            .and_then(DataType::from_code)
            .ok_or_else(|| EdsError::UnknownDataType {
                line,
                value: v.into(),
            })
    }

    fn optional_value(
        &self,
        key: &'static str,
        name: &'static str,
        dt: DataType,
        node: Option<u8>,
    ) -> Result<Option<EdsValue>, EdsError> {
        match self.section.get(key) {
            None => Ok(None),
            // An empty value means "not given" for everything but strings.
            Some(("", _)) if dt.class() != TypeClass::Bytes => Ok(None),
            Some((v, line)) => parse_value(
                &Ctx {
                    line,
                    key: name,
                    value: v,
                },
                dt,
                node,
            )
            .map(Some),
        }
    }

    fn pdo_mapping(&self, node: Option<u8>) -> Result<bool, EdsError> {
        match self.section.get("pdomapping") {
            None | Some(("", _)) => Ok(false),
            Some((v, line)) => Ok(parse_int(
                &Ctx {
                    line,
                    key: "PDOMapping",
                    value: v,
                },
                node,
            )? != 0),
        }
    }

    /// A full entry from this section alone.
    fn entry(&self, addr: Address, node: Option<u8>) -> Result<EdsEntry, EdsError> {
        let name = self.required("parametername")?.0.to_string();
        let data_type = self.data_type(node)?;
        let (acc, acc_line) = self.required("accesstype")?;
        let access = parse_access(acc, acc_line)?;
        let default = self
            .optional_value("defaultvalue", "DefaultValue", data_type, node)?
            .unwrap_or_else(|| zero(data_type));
        Ok(EdsEntry {
            addr,
            name,
            data_type,
            access,
            pdo_mappable: self.pdo_mapping(node)?,
            default,
            parameter_value: self.optional_value(
                "parametervalue",
                "ParameterValue",
                data_type,
                node,
            )?,
            low: self.optional_value("lowlimit", "LowLimit", data_type, node)?,
            high: self.optional_value("highlimit", "HighLimit", data_type, node)?,
            line: self.section.line,
        })
    }
}

fn zero(dt: DataType) -> EdsValue {
    match dt.class() {
        TypeClass::Signed => EdsValue::Signed(0),
        TypeClass::Real if dt == DataType::Real32 => EdsValue::Real32(0.0),
        TypeClass::Real => EdsValue::Real64(0.0),
        TypeClass::Bytes => EdsValue::Bytes(if dt.size() == Some(6) {
            vec![0; 6]
        } else {
            Vec::new()
        }),
        TypeClass::Unsigned => EdsValue::Unsigned(0),
    }
}

impl Eds {
    /// Parses an EDS or DCF. `node_id` resolves `$NODEID`; without it a DCF's
    /// `[DeviceComissioning] NodeID` is used, and `$NODEID` in a file without one is an error.
    pub fn parse(text: &str, node_id: Option<NodeId>) -> Result<Eds, EdsError> {
        let sections = split_sections(text)?;
        let by_name: BTreeMap<&str, &Section> =
            sections.iter().map(|s| (s.name.as_str(), s)).collect();
        let mut eds = Eds::default();
        let kv = |s: &Section| {
            s.keys
                .iter()
                .map(|(k, v, _)| (k.clone(), v.clone()))
                .collect::<BTreeMap<_, _>>()
        };
        if let Some(s) = by_name.get("FILEINFO") {
            eds.file_info = kv(s);
        }
        if let Some(s) = by_name.get("DEVICEINFO") {
            eds.device_info = kv(s);
        }
        eds.node_id = match node_id {
            Some(n) => Some(n.get()),
            None => match by_name
                .get("DEVICECOMISSIONING")
                .and_then(|s| s.get("nodeid"))
            {
                Some((v, line)) => {
                    let c = Ctx {
                        line,
                        key: "NodeID",
                        value: v,
                    };
                    let n = parse_int(&c, None)?;
                    Some(
                        u8::try_from(n)
                            .ok()
                            .filter(|n| (1..=127).contains(n))
                            .ok_or_else(|| c.bad_number())?,
                    )
                }
                None => None,
            },
        };
        let node = eds.node_id;

        // Sub sections grouped under their object.
        let mut subs: BTreeMap<u16, Vec<(u8, &Section)>> = BTreeMap::new();
        for s in &sections {
            if let SectionKind::Sub(i, sub) = section_kind(&s.name) {
                subs.entry(i).or_default().push((sub, s));
            }
        }
        for (index, list) in &subs {
            let has_object = sections
                .iter()
                .any(|o| matches!(section_kind(&o.name), SectionKind::Object(i) if i == *index));
            if let Some((_, s)) = list.first()
                && !has_object
            {
                return Err(EdsError::OrphanSub {
                    line: s.line,
                    section: s.name.clone(),
                    index: *index,
                });
            }
        }

        for s in &sections {
            let SectionKind::Object(index) = section_kind(&s.name) else {
                continue;
            };
            let mut keys = EntryKeys {
                section: s,
                domain: false,
            };
            let object_type = match s.get("objecttype") {
                None | Some(("", _)) => 7,
                Some((v, line)) => {
                    let c = Ctx {
                        line,
                        key: "ObjectType",
                        value: v,
                    };
                    let t = parse_int(&c, node)?;
                    u64::try_from(t).map_err(|_| c.bad_number())?
                }
            };
            let object_line = s.get("objecttype").map_or(s.line, |(_, l)| l);
            match object_type {
                5 | 6 => continue,
                2 | 7 => {
                    keys.domain = object_type == 2;
                    eds.entries.push(keys.entry(Address::new(index, 0), node)?)
                }
                8 | 9 => {
                    let compact = match s.get("compactsubobj") {
                        None | Some(("", _)) => 0,
                        Some((v, line)) => parse_int(
                            &Ctx {
                                line,
                                key: "CompactSubObj",
                                value: v,
                            },
                            node,
                        )?,
                    };
                    if compact > 0 {
                        eds.push_compact(s, index, compact, &by_name, node)?;
                    } else {
                        let list = subs.get(&index).map(Vec::as_slice).unwrap_or(&[]);
                        if let Some((v, line)) = s.get("subnumber") {
                            let c = Ctx {
                                line,
                                key: "SubNumber",
                                value: v,
                            };
                            let declared =
                                u64::try_from(parse_int(&c, node)?).map_err(|_| c.bad_number())?;
                            if declared != list.len() as u64 {
                                return Err(EdsError::SubNumber {
                                    line: s.line,
                                    section: s.name.clone(),
                                    declared,
                                    found: list.len(),
                                });
                            }
                        }
                        for (sub, ss) in list {
                            let k = EntryKeys {
                                section: ss,
                                domain: false,
                            };
                            eds.entries.push(k.entry(Address::new(index, *sub), node)?);
                        }
                    }
                }
                other => {
                    return Err(EdsError::UnknownObjectType {
                        line: object_line,
                        value: other,
                    });
                }
            }
        }
        eds.entries.sort_by_key(|e| e.addr);
        Ok(eds)
    }

    /// A `CompactSubObj` array: sub00 = the count, sub01..n share the object's keys.
    fn push_compact(
        &mut self,
        s: &Section,
        index: u16,
        count: i128,
        by_name: &BTreeMap<&str, &Section>,
        node: Option<u8>,
    ) -> Result<(), EdsError> {
        let (count_text, count_line) = s.get("compactsubobj").unwrap_or(("", s.line));
        let count = u8::try_from(count)
            .ok()
            .filter(|c| *c <= 254)
            .ok_or_else(|| EdsError::ValueOutOfRange {
                line: count_line,
                key: "CompactSubObj".into(),
                value: count_text.into(),
                data_type: DataType::Unsigned8,
                code: AbortCode::ValueTooHigh,
            })?;
        let keys = EntryKeys {
            section: s,
            domain: false,
        };
        let base_name = keys.required("parametername")?.0.to_string();
        self.entries.push(EdsEntry {
            addr: Address::new(index, 0),
            name: "Number of entries".into(),
            data_type: DataType::Unsigned8,
            access: AccessType::Ro,
            pdo_mappable: false,
            default: EdsValue::Unsigned(count as u64),
            parameter_value: None,
            low: None,
            high: None,
            line: s.line,
        });
        let names = by_name.get(format!("{index:04X}NAME").as_str());
        let values = by_name.get(format!("{index:04X}VALUE").as_str());
        for sub in 1..=count {
            let mut e = keys.entry(Address::new(index, sub), node)?;
            e.name = match names.and_then(|n| n.get(&sub.to_string())) {
                Some((n, _)) => n.to_string(),
                None => format!("{base_name}{sub}"),
            };
            if let Some((v, line)) = values.and_then(|n| n.get(&sub.to_string())) {
                e.parameter_value = Some(parse_value(
                    &Ctx {
                        line,
                        key: "Value",
                        value: v,
                    },
                    e.data_type,
                    node,
                )?);
            }
            self.entries.push(e);
        }
        Ok(())
    }

    /// The entry at `addr`.
    pub fn entry(&self, addr: Address) -> Option<&EdsEntry> {
        self.entries
            .binary_search_by_key(&addr, |e| e.addr)
            .ok()
            .and_then(|i| self.entries.get(i))
    }

    /// The definitions for an [`ObjectDictionary`], borrowing from `self`.
    pub fn entry_defs(&self) -> Vec<EntryDef<'_>> {
        self.entries.iter().map(EdsEntry::to_def).collect()
    }

    /// Loads every entry into `od` (with the DCF's configured values where it has them).
    pub fn load_into<'a, const N: usize, const B: usize>(
        &'a self,
        od: &mut ObjectDictionary<'a, N, B>,
    ) -> Result<(), EdsError> {
        for e in &self.entries {
            od.insert(e.to_def()).map_err(|source| EdsError::Load {
                line: e.line,
                addr: e.addr,
                source,
            })?;
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::canopen::od::ObjectAccess;

    const DRIVE: &str = include_str!("../../tests/data/cia402_drive.eds");

    fn drive() -> Eds {
        Eds::parse(DRIVE, NodeId::new(5)).unwrap()
    }

    #[test]
    fn parses_the_drive_eds() {
        let eds = drive();
        assert_eq!(
            eds.file_info.get("filename").map(String::as_str),
            Some("cia402_drive.eds")
        );
        assert_eq!(eds.node_id, Some(5));
        let e = eds.entry(Address::new(0x1000, 0)).unwrap();
        assert_eq!(e.default, EdsValue::Unsigned(0x0002_0192));
        assert_eq!(e.access, AccessType::Ro);
        // $NODEID expressions, both orders.
        assert_eq!(
            eds.entry(Address::new(0x1800, 1)).unwrap().default,
            EdsValue::Unsigned(0x185)
        );
        assert_eq!(
            eds.entry(Address::new(0x1401, 1)).unwrap().default,
            EdsValue::Unsigned(0x8000_0305)
        );
        // rww / rwr survive, and PDO mapping flags.
        let cw = eds.entry(Address::new(0x6040, 0)).unwrap();
        assert_eq!((cw.access, cw.pdo_mappable), (AccessType::Rww, true));
        assert_eq!(
            eds.entry(Address::new(0x6041, 0)).unwrap().access,
            AccessType::Ro
        );
        assert_eq!(
            eds.entry(Address::new(0x6064, 0)).unwrap().access,
            AccessType::Rwr
        );
        // Limits, including a signed limit written as a hex bit pattern.
        let t = eds.entry(Address::new(0x607D, 1)).unwrap();
        assert_eq!(t.default, EdsValue::Signed(i32::MIN as i64));
        let v = eds.entry(Address::new(0x607F, 0)).unwrap();
        assert_eq!(
            (v.low.clone(), v.high.clone()),
            (Some(EdsValue::Unsigned(1)), Some(EdsValue::Unsigned(12000)))
        );
        // Compact array with names from [1003Name] / default names, values from [1016Value].
        assert_eq!(
            eds.entry(Address::new(0x1003, 0)).unwrap().default,
            EdsValue::Unsigned(1)
        );
        assert_eq!(
            eds.entry(Address::new(0x2400, 0)).unwrap().default,
            EdsValue::Unsigned(20)
        );
        assert_eq!(
            eds.entry(Address::new(0x2400, 0x14)).unwrap().name,
            "Error-Field20"
        );
        assert_eq!(
            eds.entry(Address::new(0x2400, 2)).unwrap().data_type,
            DataType::Unsigned16
        );
        assert_eq!(
            eds.entry(Address::new(0x1016, 1)).unwrap().name,
            "Consumer heartbeat time"
        );
        assert_eq!(
            eds.entry(Address::new(0x1016, 1)).unwrap().value(),
            &EdsValue::Unsigned(0x0001_0064)
        );
        // INTEGER24, octal and a string.
        assert_eq!(
            eds.entry(Address::new(0x2100, 0)).unwrap().default,
            EdsValue::Signed(-100)
        );
        assert_eq!(
            eds.entry(Address::new(0x2101, 0)).unwrap().default,
            EdsValue::Unsigned(0o17)
        );
        assert_eq!(
            eds.entry(Address::new(0x1008, 0)).unwrap().default,
            EdsValue::Bytes(b"TLC53x simulated drive".to_vec())
        );
        // Type definitions are skipped.
        assert!(eds.entry(Address::new(0x0005, 0)).is_none());
    }

    #[test]
    fn loads_into_a_dictionary() {
        let eds = drive();
        let mut od: ObjectDictionary<'_, 128, 512> = ObjectDictionary::new();
        eds.load_into(&mut od).unwrap();
        assert_eq!(od.len(), eds.entries.len());
        assert_eq!(od.get_u32(Address::new(0x1018, 1)), Ok(0x0100_002E));
        assert_eq!(od.get_u32(Address::new(0x1A01, 2)), Ok(0x6064_0020));
        assert_eq!(
            od.write(Address::new(0x607F, 0), &20000u32.to_le_bytes()),
            Err(AbortCode::ValueTooHigh)
        );
        assert_eq!(
            od.write(Address::new(0x1000, 0), &[0; 4]),
            Err(AbortCode::ReadOnly)
        );
        let mut name = [0u8; 32];
        let n = od.read(Address::new(0x1008, 0), 0, &mut name).unwrap();
        assert_eq!(&name[..n], b"TLC53x simulated drive");
        // The default TPDO2 mapping validates against the loaded dictionary.
        let raw: Vec<u32> = (1..=2)
            .map(|s| od.get_u32(Address::new(0x1A01, s)).unwrap())
            .collect();
        let m = crate::canopen::pdo::Mapping::from_raw(&raw).unwrap();
        assert_eq!(m.validate(&od, true), Ok(()));
        assert!(m.validate(&od, false).is_err());
    }

    #[test]
    fn dcf_parameter_value_and_node_id() {
        let dcf = "[DeviceComissioning]\nNodeID=0x0A\n\
                   [1017]\nParameterName=Producer heartbeat time\nDataType=0x0006\nAccessType=rw\nDefaultValue=0\nParameterValue=100\n\
                   [1014]\nParameterName=COB-ID EMCY\nDataType=0x0007\nAccessType=rw\nDefaultValue=$NODEID+0x80\n";
        let eds = Eds::parse(dcf, None).unwrap();
        assert_eq!(eds.node_id, Some(10));
        assert_eq!(
            eds.entry(Address::new(0x1014, 0)).unwrap().default,
            EdsValue::Unsigned(0x8A)
        );
        let mut od: ObjectDictionary<'_, 4, 16> = ObjectDictionary::new();
        eds.load_into(&mut od).unwrap();
        assert_eq!(od.get_u16(Address::new(0x1017, 0)), Ok(100));
        // The caller's node-ID wins.
        let eds = Eds::parse(dcf, NodeId::new(3)).unwrap();
        assert_eq!(
            eds.entry(Address::new(0x1014, 0)).unwrap().default,
            EdsValue::Unsigned(0x83)
        );
    }

    #[test]
    fn errors_name_line_and_key() {
        let var = |body: &str| format!("[2000]\nParameterName=x\n{body}");
        let parse = |t: String| Eds::parse(&t, None).unwrap_err();
        assert_eq!(
            parse(var(
                "DataType=0x0007\nAccessType=rw\nDefaultValue=$NODEID+1"
            )),
            EdsError::NodeIdRequired {
                line: 5,
                key: "DefaultValue".into(),
                value: "$NODEID+1".into()
            }
        );
        assert_eq!(
            parse(var("DataType=0x0007\nAccessType=rw\nDefaultValue=12z")),
            EdsError::BadNumber {
                line: 5,
                key: "DefaultValue".into(),
                value: "12z".into()
            }
        );
        assert_eq!(
            parse(var("DataType=0x0005\nAccessType=rw\nHighLimit=0x100")),
            EdsError::ValueOutOfRange {
                line: 5,
                key: "HighLimit".into(),
                value: "0x100".into(),
                data_type: DataType::Unsigned8,
                code: AbortCode::ValueTooHigh
            }
        );
        assert_eq!(
            parse(var("DataType=0x0017\nAccessType=rw")),
            EdsError::UnknownDataType {
                line: 3,
                value: "0x0017".into()
            }
        );
        assert_eq!(
            parse(var("DataType=0x0007\nAccessType=readwrite")),
            EdsError::UnknownAccessType {
                line: 4,
                value: "readwrite".into()
            }
        );
        assert_eq!(
            parse(var("AccessType=rw")),
            EdsError::MissingKey {
                line: 1,
                section: "2000".into(),
                key: "DataType"
            }
        );
        assert_eq!(
            parse("[2000]\nParameterName=r\nObjectType=0x9\nSubNumber=2\n[2000sub0]\nParameterName=n\nDataType=5\nAccessType=ro\n".into()),
            EdsError::SubNumber { line: 1, section: "2000".into(), declared: 2, found: 1 }
        );
        assert_eq!(
            parse("[2001sub1]\nParameterName=n\n".into()),
            EdsError::OrphanSub {
                line: 1,
                section: "2001SUB1".into(),
                index: 0x2001
            }
        );
        assert_eq!(
            parse("ParameterName=x\n".into()),
            EdsError::KeyOutsideSection {
                line: 1,
                key: "parametername".into()
            }
        );
        assert_eq!(
            parse("[a]\n[A]\n".into()),
            EdsError::DuplicateSection {
                line: 2,
                section: "A".into()
            }
        );
        assert_eq!(
            parse("[a]\nnonsense\n".into()),
            EdsError::Syntax {
                line: 2,
                text: "nonsense".into()
            }
        );
        let too_small: Eds = Eds::parse(DRIVE, NodeId::new(1)).unwrap();
        let mut od: ObjectDictionary<'_, 4, 512> = ObjectDictionary::new();
        assert!(matches!(
            too_small.load_into(&mut od),
            Err(EdsError::Load {
                source: OdError::Full { capacity: 4, .. },
                ..
            })
        ));
    }

    /// The configuration plan run against the drive's own dictionary, as the SDO client would
    /// run it against the device: every address exists, every size matches the EDS type, the
    /// read-backs verify, and the engines built from the result send what was asked.
    #[test]
    fn plan_applied_to_the_eds_drive() {
        use crate::canopen::pdo::{
            CommParams, ConfigPlan, Mapping, PdoDirection, PdoSettings, Rpdo, RpdoEvent, Tpdo,
        };
        use crate::time::Instant;
        let eds = drive();
        let mut od: ObjectDictionary<'_, 128, 512> = ObjectDictionary::new();
        eds.load_into(&mut od).unwrap();
        let node = NodeId::new(5).unwrap();
        let tpdo2 = PdoSettings {
            direction: PdoDirection::Tpdo,
            number: 2,
            cob_id: None,
            mapping: &[0x6041_0010, 0x6064_0020],
            transmission_type: 2,
            inhibit_100us: 0,
            event_timer_ms: 0,
            sync_start: 0,
        };
        let plan = ConfigPlan::new(node, &tpdo2).unwrap();
        for w in plan.writes() {
            let size = od.size(w.addr).unwrap();
            assert_eq!(size, w.size as usize, "{}", w.addr);
            let bytes = w.value.to_le_bytes();
            od.write(w.addr, &bytes[..size]).unwrap();
        }
        for r in plan.reads() {
            let mut b = [0u8; 4];
            od.read(r.addr, 0, &mut b).unwrap();
            plan.verify(r.addr, u32::from_le_bytes(b)).unwrap();
        }
        let comm = CommParams::from_od(&od, 0x1801).unwrap();
        assert!(comm.cob_id.valid);
        let map = Mapping::from_od(&od, 0x1A01).unwrap();
        map.validate(&od, true).unwrap();
        od.set_u16(Address::new(0x6041, 0), 0x0237).unwrap();
        od.set_i32(Address::new(0x6064, 0), -5).unwrap();
        let mut tx = Tpdo::new(comm, map);
        let mut frames = Vec::new();
        for i in 0..4 {
            let mut data = [0u8; 8];
            let n = map.pack_from_od(&od, &mut data).unwrap();
            tx.set_data(&data[..n]);
            tx.handle_sync(None, Instant::from_millis(i));
            frames.extend(tx.poll_transmit(Instant::from_millis(i)));
        }
        assert_eq!(frames.len(), 2);
        assert_eq!(frames[0].to_string(), "285#3702FBFFFFFF");
        // The master's side: an RPDO with the same parameters unpacks it.
        let mut rx: Rpdo = Rpdo::new(comm, map);
        assert!(rx.handle_frame(&frames[0], Instant::ZERO));
        rx.handle_sync(Instant::ZERO);
        match rx.poll_event() {
            Some(RpdoEvent::Applied(v)) => {
                assert_eq!(v.values[0], 0x0237);
                assert_eq!(crate::canopen::pdo::sign_extend(v.values[1], 32), -5);
            }
            e => panic!("{e:?}"),
        }
    }

    #[test]
    fn domain_without_data_type() {
        let t =
            "[1F50]\nParameterName=Program\nObjectType=0x2\nAccessType=rw\nDefaultValue=prog.bin\n";
        let eds = Eds::parse(t, None).unwrap();
        let e = eds.entry(Address::new(0x1F50, 0)).unwrap();
        assert_eq!(
            (e.data_type, &e.default),
            (DataType::Domain, &EdsValue::Bytes(Vec::new()))
        );
        // A writable DOMAIN gets room to be written.
        assert_eq!(e.to_def().capacity, DEFAULT_STRING_CAPACITY);
    }

    #[test]
    fn octet_strings() {
        let t = |v: &str| {
            Eds::parse(
                &format!(
                    "[2000]\nParameterName=o\nDataType=0x000A\nAccessType=rw\nDefaultValue={v}\n"
                ),
                None,
            )
        };
        let eds = t("01 ab FF").unwrap();
        assert_eq!(
            eds.entry(Address::new(0x2000, 0)).unwrap().default,
            EdsValue::Bytes(vec![0x01, 0xAB, 0xFF])
        );
        assert!(matches!(
            t("a\u{e9}b"),
            Err(EdsError::BadNumber { line: 5, .. })
        ));
        assert!(matches!(t("abc"), Err(EdsError::BadNumber { .. })));
    }

    proptest::proptest! {
        /// Whatever the text, parsing returns (a fuzz target can call `Eds::parse` the same way).
        #[test]
        fn parse_never_panics(lines in proptest::collection::vec(
            proptest::prop_oneof![
                proptest::string::string_regex("\\[[0-9A-Fa-f]{1,4}(sub[0-9a-f]{1,3}|Name|Value)?\\]").unwrap(),
                proptest::string::string_regex("(ParameterName|ObjectType|DataType|AccessType|DefaultValue|LowLimit|HighLimit|PDOMapping|SubNumber|CompactSubObj|ParameterValue|NodeID|1|2)=[-+$0-9A-Za-zx\\u{e9} ]{0,12}").unwrap(),
                proptest::string::string_regex(".{0,10}").unwrap(),
            ],
            0..40,
        )) {
            let _ = Eds::parse(&lines.join("\n"), NodeId::new(1));
        }
    }

    #[test]
    fn numbers() {
        assert_eq!(parse_term("0x1F"), Some(31));
        assert_eq!(parse_term("017"), Some(15));
        assert_eq!(parse_term("0"), Some(0));
        assert_eq!(parse_term("-12"), Some(-12));
        assert_eq!(parse_term("09"), None);
        let c = Ctx {
            line: 1,
            key: "k",
            value: "0x200 + $nodeid",
        };
        assert_eq!(parse_int(&c, Some(7)), Ok(0x207));
    }
}
