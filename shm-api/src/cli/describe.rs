//! What `motion-cmd records` and `motion-cmd params` print: an axis's drive, link and limits, its
//! drive records, a group's record table with its step conditions, and a drive's parameter
//! table, all from the coordinator's [`MachineDescription`], in the units the machine was
//! configured in, as aligned columns. Pure functions of their inputs, so tests hold every line.

use drivers::catalog::{self, Device};
use drivers::fhpp::Variant;
use drivers::fhpp::pnu::{Access, DataType, ParamDef, Table};

use crate::contract::{
    AxisDescription, GroupDescription, GroupRecord, MAX_BUSES, MAX_DRIVE_RECORDS, MAX_GROUP_AXES,
    MAX_GROUP_RECORDS, MachineDescription, bus_kind, device, link, profile, record_mode, shape,
    target_kind,
};

use super::name_str;
use super::resolve::{ResolveError, known};
use crate::units::user;

/// ‰ of nominal as µ% (millionths of a percent), for [`user`]: 1 ‰ = 0.1 %.
const PERMILLE_AS_MICRO_PERCENT: i64 = 100_000;

/// How a column lines up.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Align {
    /// Text: padded on the right.
    Left,
    /// Numbers: padded on the left.
    Right,
}

/// Rows of text in columns, each as wide as its widest cell, two spaces apart; no trailing
/// blanks. Widths count characters, so `mm/s²` lines up like `mm/s2` would.
#[derive(Debug, Clone, Default)]
pub struct Columns {
    heads: Vec<(String, Align)>,
    rows: Vec<Vec<String>>,
}

impl Columns {
    /// Columns with these headings.
    pub fn new(heads: impl IntoIterator<Item = (String, Align)>) -> Columns {
        Columns {
            heads: heads.into_iter().collect(),
            rows: Vec::new(),
        }
    }

    /// Appends a row (missing cells are empty, extra ones ignored).
    pub fn push(&mut self, row: Vec<String>) {
        self.rows.push(row);
    }

    /// The heading line and the rows.
    pub fn lines(&self) -> Vec<String> {
        let cell = |row: &[String], i: usize| row.get(i).cloned().unwrap_or_default();
        let heads: Vec<String> = self.heads.iter().map(|(h, _)| h.clone()).collect();
        let mut widths: Vec<usize> = heads.iter().map(|h| h.chars().count()).collect();
        for row in &self.rows {
            for (i, w) in widths.iter_mut().enumerate() {
                *w = (*w).max(cell(row, i).chars().count());
            }
        }
        let line = |row: &[String]| {
            let mut s = String::new();
            for (i, (&width, (_, align))) in widths.iter().zip(&self.heads).enumerate() {
                let text = cell(row, i);
                let pad = width.saturating_sub(text.chars().count());
                if i > 0 {
                    s.push_str("  ");
                }
                match align {
                    Align::Left => {
                        s.push_str(&text);
                        s.extend(std::iter::repeat_n(' ', pad));
                    }
                    Align::Right => {
                        s.extend(std::iter::repeat_n(' ', pad));
                        s.push_str(&text);
                    }
                }
            }
            s.trim_end().to_owned()
        };
        std::iter::once(line(&heads))
            .chain(self.rows.iter().map(|r| line(r)))
            .collect()
    }
}

fn left(h: impl Into<String>) -> (String, Align) {
    (h.into(), Align::Left)
}

fn right(h: impl Into<String>) -> (String, Align) {
    (h.into(), Align::Right)
}

/// The valid axes of a description (the count is clamped: it comes from another process).
pub fn described_axes(d: &MachineDescription) -> &[AxisDescription] {
    let n = usize::from(d.axis_count).min(d.axes.len());
    d.axes.get(..n).unwrap_or(&[])
}

/// The valid groups of a description.
pub fn described_groups(d: &MachineDescription) -> &[GroupDescription] {
    let n = usize::from(d.group_count).min(d.groups.len());
    d.groups.get(..n).unwrap_or(&[])
}

/// The axis `--axis` names (by name, or by index when no axis has that name), with its index
/// (the state's and the commands' too).
pub fn find_axis<'a>(
    d: &'a MachineDescription,
    text: &str,
) -> Result<(u16, &'a AxisDescription), ResolveError> {
    let axes = described_axes(d);
    axes.iter()
        .position(|a| name_str(&a.name) == text)
        .or_else(|| text.parse::<usize>().ok().filter(|&i| i < axes.len()))
        .and_then(|i| Some((u16::try_from(i).ok()?, axes.get(i)?)))
        .ok_or_else(|| ResolveError::UnknownAxis {
            option: "--axis",
            name: text.into(),
            known: known(axes.iter().map(|a| name_str(&a.name))),
        })
}

/// The group `--group` names.
pub fn find_group<'a>(
    d: &'a MachineDescription,
    text: &str,
) -> Result<&'a GroupDescription, ResolveError> {
    let groups = described_groups(d);
    groups
        .iter()
        .find(|g| name_str(&g.name) == text)
        .or_else(|| text.parse::<usize>().ok().and_then(|i| groups.get(i)))
        .ok_or_else(|| ResolveError::UnknownGroup {
            option: "--group",
            name: text.into(),
            known: known(groups.iter().map(|g| name_str(&g.name))),
        })
}

/// The catalog's entry of a described device, if this client knows it.
pub fn catalog_device(code: u8) -> Option<&'static Device> {
    match code {
        device::MTR_DCI => Some(&catalog::MTR_DCI),
        device::EMCA => Some(&catalog::EMCA),
        device::CMMO_ST => Some(&catalog::CMMO_ST),
        device::TLC5XX => Some(&catalog::TLC5XX),
        device::CIA402 => Some(&catalog::CIA402_GENERIC),
        _ => None,
    }
}

/// The drive by vendor and name: `Festo EMCA`, `Schneider TLC5xx`.
pub fn device_name(code: u8) -> String {
    match catalog_device(code) {
        Some(d) => format!("{} {}", d.vendor, d.name),
        None => format!("an unknown device (code {code})"),
    }
}

/// The FHPP variant of a described device (its PNU table), or `None` for the TLC5xx.
pub fn fhpp_variant(code: u8) -> Option<Variant> {
    match code {
        device::MTR_DCI => Some(Variant::MtrDci),
        device::EMCA => Some(Variant::Emca),
        device::CMMO_ST => Some(Variant::CmmoSt),
        _ => None,
    }
}

/// Where the drive is: `node 2 on can1 (simulated)`, `node 1 on vbus:can0`, `Modbus TCP
/// 127.0.0.1:1502`, `Modbus TCP (simulated)`.
pub fn link_text(d: &MachineDescription, a: &AxisDescription) -> String {
    match a.link {
        link::MODBUS if a.simulated != 0 => "Modbus TCP (simulated)".into(),
        link::MODBUS => format!("Modbus TCP {}", name_str(&a.modbus)),
        link::ETHERCAT => format!("subdevice {} on EtherCAT {}", a.node, name_str(&a.modbus)),
        _ => {
            let bus = d
                .buses
                .get(usize::from(a.bus))
                .filter(|_| usize::from(a.bus) < usize::from(d.bus_count).min(MAX_BUSES));
            let label = match bus {
                Some(b) if b.kind == bus_kind::VBUS => format!("vbus:{}", name_str(&b.name)),
                Some(b) if b.kind == bus_kind::SIMULATED => {
                    format!("{} (simulated)", name_str(&b.name))
                }
                Some(b) => name_str(&b.name).to_owned(),
                None => format!("bus {}", a.bus),
            };
            format!("node {} on {label}", a.node)
        }
    }
}

fn profile_name(code: u8) -> &'static str {
    match code {
        profile::FHPP => "FHPP",
        profile::CIA402 => "CiA 402",
        _ => "an unknown profile",
    }
}

/// The axis's first line: `axis y: Festo EMCA, FHPP, node 2 on can1 (simulated), parameter
/// channel`.
pub fn axis_heading(d: &MachineDescription, a: &AxisDescription) -> String {
    format!(
        "axis {}: {}, {}, {}, {}",
        name_str(&a.name),
        device_name(a.device),
        profile_name(a.profile),
        link_text(d, a),
        if a.fpc != 0 {
            "parameter channel"
        } else {
            "no parameter channel"
        }
    )
}

/// The axis's limits in its unit: `limits: position 0..=250 mm, velocity 80 mm/s, ...`.
pub fn limits_line(a: &AxisDescription) -> String {
    let unit = name_str(&a.unit);
    let mut s = format!(
        "limits: position {}..={} {unit}, velocity {} {unit}/s, acceleration {} {unit}/s²",
        user(a.position_min),
        user(a.position_max),
        user(a.velocity),
        user(a.acceleration)
    );
    if a.jerk != 0 {
        s.push_str(&format!(", jerk {} {unit}/s³", user(a.jerk)));
    }
    if a.force_permille != 0 {
        s.push_str(&format!(
            ", force {} %",
            user(i64::from(a.force_permille) * PERMILLE_AS_MICRO_PERCENT)
        ));
    }
    s.push_str(&format!(
        ", following error {} {unit}",
        user(a.following_error)
    ));
    s
}

/// `motion-cmd records --axis NAME`: the axis, its limits and its drive's record table.
pub fn axis_records(d: &MachineDescription, a: &AxisDescription) -> Vec<String> {
    let mut lines = vec![axis_heading(d, a), limits_line(a)];
    let unit = name_str(&a.unit);
    let count = usize::from(a.record_count).min(MAX_DRIVE_RECORDS);
    let table = catalog_device(a.device).and_then(|dev| dev.records);
    if count == 0 {
        lines.push(match table {
            Some(t) => format!(
                "no drive records configured (records 1..={} of the {} table; [[records]] in \
                 the configuration)",
                t.last,
                device_name(a.device)
            ),
            None => {
                let group = described_groups(d).iter().find(|g| {
                    group_member_indices(g).iter().any(|&m| {
                        described_axes(d).get(usize::from(m)).map(|x| x.name) == Some(a.name)
                    })
                });
                match group {
                    Some(g) => format!(
                        "the {} has no record table of its own: its moves are the records of \
                         group {} (motion-cmd records --group {})",
                        device_name(a.device),
                        name_str(&g.name),
                        name_str(&g.name)
                    ),
                    None => format!(
                        "the {} has no record table of its own (group records move it)",
                        device_name(a.device)
                    ),
                }
            }
        });
        return lines;
    }
    lines.push(format!(
        "{count} drive record{} configured{}:",
        if count == 1 { "" } else { "s" },
        table.map_or(String::new(), |t| format!(
            " (the {} holds records 1..={})",
            device_name(a.device),
            t.last
        ))
    ));
    let mut cols = Columns::new([
        right("record"),
        right(format!("position [{unit}]")),
        left("kind"),
        right(format!("velocity [{unit}/s]")),
        right(format!("acceleration [{unit}/s²]")),
        right("next"),
    ]);
    for r in &a.records[..count] {
        cols.push(vec![
            r.number.to_string(),
            user(r.position),
            if r.relative != 0 {
                "relative"
            } else {
                "absolute"
            }
            .into(),
            user(r.velocity),
            user(r.acceleration),
            if r.next == 0 {
                "-".into()
            } else {
                r.next.to_string()
            },
        ]);
    }
    lines.extend(cols.lines());
    lines
}

fn group_member_indices(g: &GroupDescription) -> &[u8] {
    let n = usize::from(g.axis_count).min(MAX_GROUP_AXES);
    g.axes.get(..n).unwrap_or(&[])
}

/// A group record's target for one member: `200`, `by -40` (relative), `keep`.
fn target_text(r: &GroupRecord, k: usize) -> String {
    let v = r.targets.get(k).copied().unwrap_or(0);
    match r.target_kinds.get(k).copied().unwrap_or(target_kind::KEEP) {
        target_kind::ABSOLUTE => user(v),
        target_kind::RELATIVE if v >= 0 => format!("by +{}", user(v)),
        target_kind::RELATIVE => format!("by {}", user(v)),
        _ => "keep".into(),
    }
}

/// A condition and where it leads: `position x in [150, 210] mm for 10 ms → 11`.
fn leads(condition: &[u8], next: i16) -> String {
    format!("{} → {next}", name_str(condition))
}

/// `motion-cmd records --group NAME`: the group's members and record table, each record's step
/// condition (and alternative, on the line below) in words.
pub fn group_records(d: &MachineDescription, g: &GroupDescription) -> Vec<String> {
    let axes = described_axes(d);
    let members: Vec<&AxisDescription> = group_member_indices(g)
        .iter()
        .filter_map(|&m| axes.get(usize::from(m)))
        .collect();
    let names: Vec<&str> = members.iter().map(|a| name_str(&a.name)).collect();
    let count = usize::from(g.record_count).min(MAX_GROUP_RECORDS);
    let scurve = g.shape == shape::S_CURVE;
    let mut lines = vec![format!(
        "group {}: axes {}, {} profile, {count} record{}",
        name_str(&g.name),
        if names.is_empty() {
            "none".into()
        } else {
            names.join(", ")
        },
        if scurve { "S-curve" } else { "trapezoid" },
        if count == 1 { "" } else { "s" }
    )];
    if count == 0 {
        lines.push("no records: the group moves only by commands".into());
        return lines;
    }
    let records = &g.records[..count];
    let modes = records.iter().any(|r| r.mode != record_mode::POSITION);
    let mut heads = vec![right("record")];
    heads.extend(
        members
            .iter()
            .map(|a| right(format!("{} [{}]", name_str(&a.name), name_str(&a.unit)))),
    );
    if modes {
        heads.push(left("mode"));
    }
    heads.push(right("velocity"));
    heads.push(right("acceleration"));
    if scurve {
        heads.push(right("jerk"));
    }
    heads.push(right("delay"));
    heads.push(left("step"));
    let step_col = heads.len() - 1;
    let mut cols = Columns::new(heads);
    for r in records {
        let mut row = vec![r.number.to_string()];
        row.extend((0..members.len()).map(|k| target_text(r, k)));
        if modes {
            row.push(match r.mode {
                record_mode::VELOCITY => "velocity".into(),
                record_mode::FORCE => {
                    format!(
                        "force {} %",
                        user(i64::from(r.force_permille) * PERMILLE_AS_MICRO_PERCENT)
                    )
                }
                _ => "position".into(),
            });
        }
        row.push(format!("{} %", r.velocity_percent));
        row.push(format!("{} %", r.acceleration_percent));
        if scurve {
            row.push(format!("{} %", r.jerk_percent));
        }
        row.push(format!("{} ms", r.delay_ms));
        row.push(if r.step_next < 0 {
            "end of chain".into()
        } else {
            leads(&r.step, r.step_next)
        });
        cols.push(row);
        let below = |text: String| {
            let mut row = vec![String::new(); step_col];
            row.push(text);
            row
        };
        if r.alternative_next >= 0 {
            cols.push(below(format!(
                "or {}",
                leads(&r.alternative, r.alternative_next)
            )));
        }
        if r.mc_in_chain == 0 && r.step_next >= 0 {
            cols.push(below("(no MC shown inside the chain)".into()));
        }
    }
    lines.extend(cols.lines());
    lines
}

/// A parameter's name and unit: the PNU tables write the unit in brackets
/// (`Actual position [SINC]`, `Feed constant [SINC]/revolutions`).
pub fn name_and_unit(text: &str) -> (String, String) {
    let Some(open) = text.rfind('[') else {
        return (text.to_owned(), String::new());
    };
    let Some(len) = text[open..].find(']') else {
        return (text.to_owned(), String::new());
    };
    let before = text[..open].trim_end();
    let inside = &text[open + 1..open + len];
    let after = &text[open + len + 1..];
    // A unit that goes on after the bracket (`[SINC]/revolutions`) belongs to it.
    let (more, rest) = match after.strip_prefix('/') {
        Some(tail) => {
            let end = tail.find(char::is_whitespace).unwrap_or(tail.len());
            (format!("/{}", &tail[..end]), &tail[end..])
        }
        None => (String::new(), after),
    };
    let name = format!("{before}{rest}").trim().to_owned();
    (name, format!("{inside}{more}"))
}

/// A data type as the manuals write it.
pub fn type_name(t: DataType) -> &'static str {
    match t {
        DataType::U8 => "u8",
        DataType::I8 => "i8",
        DataType::U16 => "u16",
        DataType::I16 => "i16",
        DataType::U32 => "u32",
        DataType::I32 => "i32",
        DataType::Char => "char",
    }
}

/// The entries of a device's PNU table, as `params` lists them: the device's own first, then the
/// FHPP family's that it does not shadow, each (PNU, sub-index range) once, by PNU.
pub fn parameter_entries(variant: Variant) -> Vec<&'static ParamDef> {
    let table = Table::of(variant);
    let mut v: Vec<&'static ParamDef> = table
        .entries()
        // The device's own: what a read of the entry's first sub-index finds is this entry (a
        // family entry for a PNU the device defines itself is shadowed by the device's).
        .filter(|&d| {
            table
                .lookup(drivers::fhpp::fpc::Param::new(d.pnu, d.first_sub))
                .is_ok_and(|found| core::ptr::eq(found, d))
        })
        .collect();
    v.sort_by_key(|d| (d.pnu, d.first_sub));
    v
}

/// Whether `params` reads an entry's value without `--pnu`: one readable number (arrays and
/// texts are read with `--pnu`).
pub fn is_simple(d: &ParamDef) -> bool {
    d.first_sub == d.last_sub && d.access != Access::Wo && d.dtype != DataType::Char
}

/// The sub-index range of an entry: `1`, `1..64`.
pub fn subs_text(d: &ParamDef) -> String {
    if d.first_sub == d.last_sub {
        d.first_sub.to_string()
    } else {
        format!("{}..{}", d.first_sub, d.last_sub)
    }
}

/// A value the drive returned, as the parameter's type reads it. The event carries the
/// channel's value zero-extended to 32 bits: EFPC sends every value as 32 bits (signed ones
/// sign-extended), classic FPC in the type's width, so the type's own width is taken.
pub fn decode(d: &ParamDef, raw: i64) -> i64 {
    use drivers::fhpp::fpc::Value;
    let v = raw as u32;
    let width = match d.dtype {
        DataType::U8 | DataType::I8 | DataType::Char => Value::Byte(v as u8),
        DataType::U16 | DataType::I16 => Value::Word(v as u16),
        DataType::U32 | DataType::I32 => Value::Dword(v),
    };
    d.dtype.decode(width)
}

/// What the value column says of an entry `params` did not read.
pub fn unread_text(d: &ParamDef, axis: &str) -> String {
    if d.access == Access::Wo {
        "(write-only)".into()
    } else if d.dtype == DataType::Char {
        format!("(text: --axis {axis} --pnu {})", d.pnu)
    } else {
        format!(
            "({} values: --axis {axis} --pnu {})",
            usize::from(d.last_sub - d.first_sub) + 1,
            d.pnu
        )
    }
}

/// The parameter table's columns; `values` adds the value column.
pub fn parameter_columns(values: bool) -> Columns {
    let mut heads = vec![
        right("PNU"),
        left("sub"),
        left("name"),
        left("type"),
        left("unit"),
    ];
    if values {
        heads.push(left("value"));
    }
    Columns::new(heads)
}

/// A row of the parameter table (without its value).
pub fn parameter_row(d: &ParamDef) -> Vec<String> {
    let (name, unit) = name_and_unit(d.name);
    vec![
        d.pnu.to_string(),
        subs_text(d),
        name,
        type_name(d.dtype).into(),
        unit,
    ]
}

/// Characters read one sub-index at a time, as text (up to the first NUL; bytes that are not
/// printable ASCII shown as `?`).
pub fn chars_text(values: &[i64]) -> String {
    values
        .iter()
        .map(|&v| (v & 0xFF) as u8)
        .take_while(|&b| b != 0)
        .map(|b| {
            if b.is_ascii_graphic() || b == b' ' {
                b as char
            } else {
                '?'
            }
        })
        .collect()
}

/// The entries of a device's parameter table for `pnu` (none: the device has no such PNU).
pub fn entries_of(variant: Variant, pnu: u16) -> Vec<&'static ParamDef> {
    parameter_entries(variant)
        .into_iter()
        .filter(|d| d.pnu == pnu)
        .collect()
}

/// A drive's refusal of a parameter task in words, from its error number in the device's
/// dialect (classic FPC on the MTR-DCI, EFPC on the EMCA and CMMO-ST): `error 17: not possible
/// in the drive's state (PNU 534 is written only with the output stage off: disable the axis
/// first)`. Without a known device, the number alone.
pub fn drive_error_text(device: Option<u8>, pnu: u16, sub: u8, number: i64) -> String {
    use drivers::fhpp::fpc::{ErrorKind, Param};
    let Some(variant) = device.and_then(fhpp_variant) else {
        return format!("error {number}");
    };
    let n = u16::try_from(number).unwrap_or(u16::MAX);
    let stage_off = Table::of(variant)
        .lookup(Param::new(pnu, sub))
        .is_ok_and(|d| d.access == Access::Rw2);
    let words = match ErrorKind::from_number(n, variant.parameter_channel()) {
        ErrorKind::NoSuchPnu => "no such parameter".into(),
        ErrorKind::ReadOnly => "the parameter is read-only".into(),
        ErrorKind::WriteOnly => "the parameter is write-only".into(),
        ErrorKind::OutOfRange => "the value is outside the parameter's limits".into(),
        ErrorKind::BadSubindex => "no such sub-index".into(),
        ErrorKind::NotArray => "the parameter is not an array".into(),
        ErrorKind::WrongType => "the value's type does not fit the parameter".into(),
        ErrorKind::NoControl => "the fieldbus does not hold device control".into(),
        ErrorKind::NotInThisState if stage_off => format!(
            "not possible in the drive's state (PNU {pnu} is written only with the output \
             stage off: disable the axis first)"
        ),
        ErrorKind::NotInThisState => "not possible in the drive's state".into(),
        // Classic FPC's 22 stands for several refusals.
        ErrorKind::UnsupportedTask => {
            "the drive does not accept this task (limits, attributes or type)".into()
        }
        ErrorKind::Other(_) => String::new(),
    };
    if words.is_empty() {
        format!("error {number}")
    } else {
        format!("error {number}: {words}")
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::contract::{GroupRecord, MICRO};
    use crate::request::name_bytes;

    /// x (an MTR-DCI in mm, no records) and y (an EMCA with two records, one relative) on
    /// can0 and can1, group xy with three records.
    fn machine() -> Box<MachineDescription> {
        // SAFETY: integers only; all-zero bytes are a valid value.
        let mut d = unsafe { Box::<MachineDescription>::new_zeroed().assume_init() };
        d.axis_count = 2;
        d.group_count = 1;
        d.bus_count = 2;
        for (i, (name, kind)) in [("can0", bus_kind::VBUS), ("can1", bus_kind::SIMULATED)]
            .into_iter()
            .enumerate()
        {
            d.buses[i].name = name_bytes(name);
            d.buses[i].kind = kind;
        }
        let x = &mut d.axes[0];
        x.name = name_bytes("x");
        x.unit = name_bytes("mm");
        x.device = device::MTR_DCI;
        (x.bus, x.node) = (0, 1);
        (x.position_min, x.position_max) = (-5 * MICRO, 400 * MICRO);
        (x.velocity, x.acceleration, x.jerk) = (150 * MICRO, 1000 * MICRO, 20_000 * MICRO);
        (x.force_permille, x.following_error) = (1000, 16_800_000);
        let y = &mut d.axes[1];
        y.name = name_bytes("y");
        y.unit = name_bytes("mm");
        y.device = device::EMCA;
        y.fpc = 1;
        (y.bus, y.node, y.simulated) = (1, 2, 1);
        (y.position_max, y.velocity, y.acceleration) = (250 * MICRO, 80 * MICRO, 400 * MICRO);
        y.following_error = 8_960_000;
        y.record_count = 2;
        for (r, (n, pos, rel, v, a, next)) in y.records.iter_mut().zip([
            (1, 10 * MICRO, 0, 60 * MICRO, 400 * MICRO, 2),
            (2, -2_500_000, 1, 80 * MICRO, 300 * MICRO, 0),
        ]) {
            (r.number, r.position, r.relative) = (n, pos, rel);
            (r.velocity, r.acceleration, r.next) = (v, a, next);
        }
        let g = &mut d.groups[0];
        g.name = name_bytes("xy");
        g.axis_count = 2;
        g.axes[1] = 1;
        g.record_count = 3;
        let record = |number: u16, targets: [(u8, i64); 2], step: (&str, i16)| {
            // SAFETY: integers only.
            let mut r: GroupRecord = unsafe { core::mem::zeroed() };
            r.number = number;
            for (k, (kind, v)) in targets.into_iter().enumerate() {
                (r.target_kinds[k], r.targets[k]) = (kind, v);
            }
            (r.velocity_percent, r.acceleration_percent, r.mc_in_chain) = (100, 100, 1);
            (r.step, r.step_next, r.alternative_next) = (name_bytes(step.0), step.1, -1);
            r
        };
        g.records[0] = record(
            10,
            [
                (target_kind::ABSOLUTE, 200 * MICRO),
                (target_kind::ABSOLUTE, 100 * MICRO),
            ],
            ("position x in [150, 210] mm for 10 ms", 11),
        );
        g.records[0].velocity_percent = 80;
        g.records[1] = record(
            11,
            [
                (target_kind::RELATIVE, 100 * MICRO),
                (target_kind::RELATIVE, -40 * MICRO),
            ],
            ("motion complete", 12),
        );
        g.records[1].delay_ms = 50;
        g.records[1].mc_in_chain = 0;
        (g.records[1].alternative, g.records[1].alternative_next) =
            (name_bytes("input 0 rising"), 10);
        g.records[2] = record(
            12,
            [(target_kind::KEEP, 0), (target_kind::ABSOLUTE, 0)],
            ("", -1),
        );
        d
    }

    #[test]
    fn an_axis_reads_with_its_drive_link_limits_and_records() {
        let d = machine();
        assert_eq!(
            axis_records(&d, &d.axes[1]),
            [
                "axis y: Festo EMCA, FHPP, node 2 on can1 (simulated), parameter channel",
                "limits: position 0..=250 mm, velocity 80 mm/s, acceleration 400 mm/s², \
                 following error 8.96 mm",
                "2 drive records configured (the Festo EMCA holds records 1..=64):",
                "record  position [mm]  kind      velocity [mm/s]  acceleration [mm/s²]  next",
                "     1             10  absolute               60                   400     2",
                "     2           -2.5  relative               80                   300     -",
            ]
        );
        assert_eq!(
            axis_records(&d, &d.axes[0]),
            [
                "axis x: Festo MTR-DCI, FHPP, node 1 on vbus:can0, no parameter channel",
                "limits: position -5..=400 mm, velocity 150 mm/s, acceleration 1000 mm/s², \
                 jerk 20000 mm/s³, force 100 %, following error 16.8 mm",
                "no drive records configured (records 1..=31 of the Festo MTR-DCI table; \
                 [[records]] in the configuration)",
            ]
        );
    }

    #[test]
    fn a_group_reads_with_its_targets_and_conditions_in_words() {
        let d = machine();
        assert_eq!(
            group_records(&d, &d.groups[0]),
            [
                "group xy: axes x, y, trapezoid profile, 3 records",
                "record   x [mm]  y [mm]  velocity  acceleration  delay  step",
                "    10      200     100      80 %         100 %   0 ms  position x in [150, 210] mm for 10 ms → 11",
                "    11  by +100  by -40     100 %         100 %  50 ms  motion complete → 12",
                "                                                        or input 0 rising → 10",
                "                                                        (no MC shown inside the chain)",
                "    12     keep       0     100 %         100 %   0 ms  end of chain",
            ]
        );
    }

    #[test]
    fn names_are_found_or_refused_naming_option_and_choices() {
        let d = machine();
        assert_eq!(find_axis(&d, "y").map(|(i, _)| i), Ok(1));
        assert_eq!(find_axis(&d, "0").map(|(i, _)| i), Ok(0));
        assert_eq!(
            find_axis(&d, "w").err().map(|e| e.to_string()).as_deref(),
            Some("--axis w: no such axis; the axes are x, y")
        );
        assert_eq!(
            find_axis(&d, "2").err().map(|e| e.to_string()).as_deref(),
            Some("--axis 2: no such axis; the axes are x, y")
        );
        assert_eq!(
            find_group(&d, "g").err().map(|e| e.to_string()).as_deref(),
            Some("--group g: no such group; the groups are xy")
        );
    }

    #[test]
    fn parameters_come_from_the_device_table_with_names_and_units() {
        assert_eq!(
            name_and_unit("Sample position, rising edge [SINC]"),
            ("Sample position, rising edge".into(), "SINC".into())
        );
        assert_eq!(
            name_and_unit("Jerk acceleration [(SINC/s³)/10] (0 = max)"),
            ("Jerk acceleration (0 = max)".into(), "(SINC/s³)/10".into())
        );
        assert_eq!(
            name_and_unit("Feed constant [SINC]/revolutions"),
            ("Feed constant".into(), "SINC/revolutions".into())
        );
        assert_eq!(
            name_and_unit("Homing method"),
            ("Homing method".into(), String::new())
        );
        for v in [Variant::MtrDci, Variant::Emca, Variant::CmmoSt] {
            let e = parameter_entries(v);
            // Each (PNU, first sub-index) once, in order, and each the device's own reading.
            for w in e.windows(2) {
                assert!(
                    (w[0].pnu, w[0].first_sub) < (w[1].pnu, w[1].first_sub),
                    "{v:?}"
                );
            }
        }
        // The EMCA's 1001 is its own (increments and revolutions), not the family's.
        let enc = entries_of(Variant::Emca, 1001);
        assert_eq!(enc.len(), 2);
        assert_eq!(enc[0].default, 4096);
        assert!(entries_of(Variant::Emca, 9999).is_empty());
        let row = parameter_row(enc[0]);
        assert_eq!(
            row,
            ["1001", "1", "Encoder resolution", "u32", "increments"]
        );
        // Signed values read as their type.
        let homing = entries_of(Variant::Emca, 1011)[0];
        // The EMCA sends -35 in 32 bits, the MTR-DCI's classic channel in 8.
        assert_eq!(decode(homing, 0xFFFF_FFDD), -35);
        assert_eq!(decode(homing, 0xDD), -35);
        assert_eq!(decode(enc[0], 4096), 4096);
        assert_eq!(chars_text(&[0x45, 0x4D, 0x01, 0x41, 0]), "EM?A");
    }

    #[test]
    fn drive_refusals_read_in_words() {
        assert_eq!(
            drive_error_text(Some(device::EMCA), 534, 1, 0x11),
            "error 17: not possible in the drive's state (PNU 534 is written only with the \
             output stage off: disable the axis first)"
        );
        assert_eq!(
            drive_error_text(Some(device::EMCA), 520, 1, 2),
            "error 2: the value is outside the parameter's limits"
        );
        assert_eq!(
            drive_error_text(Some(device::MTR_DCI), 100, 0, 1),
            "error 1: the parameter is read-only"
        );
        assert_eq!(drive_error_text(None, 1, 0, 17), "error 17");
        assert_eq!(
            drive_error_text(Some(device::EMCA), 1, 0, 0x99),
            "error 153"
        );
    }

    #[test]
    fn columns_align_by_characters_and_trim_the_end() {
        let mut c = Columns::new([right("n"), left("unit"), left("x")]);
        c.push(vec!["10".into(), "mm/s²".into()]);
        c.push(vec!["7".into(), "µm".into(), "a".into()]);
        assert_eq!(c.lines(), [" n  unit   x", "10  mm/s²", " 7  µm     a"]);
    }
}
