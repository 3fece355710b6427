//! What the coordinator reads from a generic CiA 402 drive's EDS (CiA 306, `eds = "path"` on a
//! `cia402` axis): its identity, the modes it supports (6502h), which objects it lets a PDO
//! map, and which parameters it has. `check` refuses a mode or a mapping the drive cannot take,
//! naming the object; the boot expects the identity and writes only parameters that exist.

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

use drivers::canopen::eds::{Eds, EdsValue};
use drivers::canopen::od::AccessType;
use drivers::cia402::modes::OperationMode;

use crate::axis::CyclicMode;

/// The objects every CiA 402 axis of the coordinator maps (besides the set-point):
/// controlword, modes of operation (RPDO); statusword, position actual, modes display (TPDO).
const ALWAYS_MAPPED: [u32; 5] = [
    0x6040_0010,
    0x6060_0008,
    0x6041_0010,
    0x6064_0020,
    0x6061_0008,
];

/// A drive's EDS, as far as the coordinator uses it.
#[derive(Clone, Debug, PartialEq)]
pub struct DriveEds {
    /// Where it was read from (for messages).
    pub path: PathBuf,
    /// 1000h's default: the device type the boot expects.
    pub device_type: Option<u32>,
    /// 1018h:01's default: the vendor-ID the boot expects.
    pub vendor_id: Option<u32>,
    /// 1018h:02's default.
    pub product_code: Option<u32>,
    /// 6502h's default: the supported drive modes (bit n − 1 for mode n).
    pub modes: Option<u32>,
    /// Every entry: (mappable, writable), by (index, sub-index).
    entries: BTreeMap<(u16, u8), (bool, bool)>,
}

fn unsigned(v: &EdsValue) -> Option<u32> {
    match v {
        EdsValue::Unsigned(u) => u32::try_from(*u).ok(),
        EdsValue::Signed(s) => u32::try_from(*s).ok(),
        _ => None,
    }
}

impl DriveEds {
    /// Reads and parses the EDS at `path`.
    pub fn read(path: &Path) -> Result<DriveEds, String> {
        let text = std::fs::read_to_string(path)
            .map_err(|e| format!("cannot read the EDS {}: {e}", path.display()))?;
        DriveEds::parse(&text, path)
    }

    /// Parses an EDS text (`path` names it in messages). `$NODEID` terms resolve against node 1:
    /// only defaults the coordinator does not use depend on it.
    pub fn parse(text: &str, path: &Path) -> Result<DriveEds, String> {
        let eds = Eds::parse(text, drivers::canopen::NodeId::new(1))
            .map_err(|e| format!("the EDS {}: {e}", path.display()))?;
        let value = |index: u16, sub: u8| {
            eds.entry(drivers::canopen::Address::new(index, sub))
                .and_then(|e| unsigned(e.value()))
        };
        let entries = eds
            .entries
            .iter()
            .map(|e| {
                let writable = matches!(
                    e.access,
                    AccessType::Rw | AccessType::Rwr | AccessType::Rww | AccessType::Wo
                );
                ((e.addr.index, e.addr.sub), (e.pdo_mappable, writable))
            })
            .collect();
        Ok(DriveEds {
            path: path.to_path_buf(),
            device_type: value(0x1000, 0),
            vendor_id: value(0x1018, 1),
            product_code: value(0x1018, 2),
            modes: value(0x6502, 0),
            entries,
        })
    }

    /// Whether the drive supports `mode` (6502h; a file without 6502h supports none).
    pub fn supports(&self, mode: OperationMode) -> bool {
        let bit = mode.supported_modes_bit();
        self.modes.zip(bit).is_some_and(|(m, mask)| m & mask != 0)
    }

    /// Whether the object of a mapping entry (`index << 16 | sub << 8 | bits`) can be mapped.
    pub fn mappable(&self, entry: u32) -> bool {
        let key = ((entry >> 16) as u16, (entry >> 8) as u8);
        self.entries.get(&key).is_some_and(|(m, _)| *m)
    }

    /// Whether the object exists and the master may write it.
    pub fn writable(&self, index: u16, sub: u8) -> bool {
        self.entries.get(&(index, sub)).is_some_and(|(_, w)| *w)
    }

    /// What the drive lacks to be commanded in `mode`, in words (empty: nothing).
    pub fn lacks(&self, mode: CyclicMode) -> Vec<String> {
        let mut why = Vec::new();
        if !self.supports(mode.operation_mode()) {
            why.push(format!(
                "its 6502h (supported drive modes{}) has no {mode} (mode {})",
                self.modes
                    .map_or(String::from(": absent"), |m| format!(" = {m:08X}h")),
                mode.operation_mode().code()
            ));
        }
        for entry in ALWAYS_MAPPED.into_iter().chain([mode.setpoint_entry()]) {
            if !self.mappable(entry) {
                why.push(format!(
                    "{:04X}h sub {} is not PDO-mappable in it",
                    entry >> 16,
                    (entry >> 8) as u8
                ));
            }
        }
        // The boot maps PDO1 itself (and reads it back): a static mapping cannot take it.
        for (index, what) in [(0x1600, "RPDO1"), (0x1A00, "TPDO1")] {
            if !self.writable(index, 0) {
                why.push(format!(
                    "its {index:04X}h sub 0 ({what} mapping) is not writable: the coordinator maps PDO1 itself, a drive with a static PDO1 mapping cannot be used"
                ));
            }
        }
        if mode != CyclicMode::Pp && !self.writable(0x60C2, 1) {
            why.push("it has no writable 60C2h sub 1 (interpolation time period)".into());
        }
        why
    }
}
