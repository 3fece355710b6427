//! The controlword 6040h (U16): the master's commands to the device state machine and the
//! mode-specific bits, with the manuals' bit names (CiA 402; TLC5xx §3.2 of the digest;
//! MTR-DCI Tab. C/3).
//!
//! ```
//! use drivers::cia402::controlword::{AbsRel, Command, Controlword};
//! let cw = Controlword::from_bytes([0x1F, 0x00]);
//! assert_eq!(cw.command(), Command::EnableOperation);
//! assert!(cw.new_set_point());
//! // The TLC5xx manual's polarity: bit 6 = 0 means relative (digest erratum A1).
//! assert!(cw.is_relative(AbsRel::ZeroIsRelative));
//! assert!(!cw.is_relative(AbsRel::ZeroIsAbsolute));
//! ```

/// A controlword value. Any 16-bit value is valid: unknown bits are kept, never rejected.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Default)]
pub struct Controlword(pub u16);

/// The meaning of controlword bit 6 in profile position mode ("abs/rel").
///
/// CiA 402 and the MTR-DCI (Tab. C/3) use 0 = absolute, 1 = relative. The TLC5xx manual
/// (§5.3.2, 6040h) prints the reverse, 0 = relative, 1 = absolute, and its own trace (§5.4.3:
/// controlword 001Fh for a relative move of 1500) agrees with the print; the digest (erratum A1)
/// suggests following the manual by default with a switch, so the TLC5xx profile defaults to
/// [`AbsRel::ZeroIsRelative`].
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum AbsRel {
    /// CiA 402: bit 6 = 0 absolute, 1 relative.
    ZeroIsAbsolute,
    /// TLC5xx manual as printed: bit 6 = 0 relative, 1 absolute.
    ZeroIsRelative,
}

/// The device-control command encoded in bits 0..3 (bit 7, fault reset, is an edge and is
/// evaluated separately by the state machine).
///
/// The decoding is total: every controlword is exactly one command, checked in the order of the
/// CiA 402 command table (disable voltage wins over quick stop, which wins over the rest).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum Command {
    /// `x x x 0 x` (bit 1 enable voltage = 0): transitions 7, 9, 10, 12. Sent as 0000h.
    DisableVoltage,
    /// `x x 0 1 x` (bit 2 quick stop = 0, low active): transitions 7, 10, 11. Sent as 0002h.
    QuickStop,
    /// `x x 1 1 0`: transitions 2, 6, 8. Sent as 0006h.
    Shutdown,
    /// `x 0 1 1 1`: switch on (3) or disable operation (5). Sent as 0007h.
    SwitchOn,
    /// `x 1 1 1 1`: transitions 4 and 16 (and 3 + 4 from Ready to switch on). Sent as 000Fh.
    EnableOperation,
}

impl Command {
    /// The controlword that carries this command with every other bit 0.
    pub const fn controlword(self) -> Controlword {
        Controlword(match self {
            Command::DisableVoltage => 0x0000,
            Command::QuickStop => 0x0002,
            Command::Shutdown => 0x0006,
            Command::SwitchOn => 0x0007,
            Command::EnableOperation => 0x000F,
        })
    }
}

impl Controlword {
    /// Bit 0 "switch on".
    pub const SWITCH_ON: u16 = 1 << 0;
    /// Bit 1 "enable voltage" (the TLC5xx manual names the command "disable voltage": 0 commands it).
    pub const ENABLE_VOLTAGE: u16 = 1 << 1;
    /// Bit 2 "quick stop", low active: 0 requests a quick stop.
    pub const QUICK_STOP: u16 = 1 << 2;
    /// Bit 3 "enable operation".
    pub const ENABLE_OPERATION: u16 = 1 << 3;
    /// Bit 4, mode specific: profile position "new set-point" (rising edge), homing "start homing
    /// operation"; unused in profile velocity.
    pub const NEW_SET_POINT: u16 = 1 << 4;
    /// Bit 4 under its homing-mode name.
    pub const HOMING_START: u16 = 1 << 4;
    /// Bit 5, profile position "change set immediately" (1 = the new set-point replaces the running
    /// one, 0 = it waits until the running one is reached). Not supported by the MTR-DCI; on the
    /// MTR-DCI in profile torque mode it enables the stroke limit.
    pub const CHANGE_SET_IMMEDIATELY: u16 = 1 << 5;
    /// Bit 6, profile position "abs/rel"; its polarity is device specific, see [`AbsRel`].
    pub const ABS_REL: u16 = 1 << 6;
    /// Bit 7 "fault reset": a rising edge resets a fault (transition 15).
    pub const FAULT_RESET: u16 = 1 << 7;
    /// Bit 8 "halt": 1 stops on the profile deceleration and keeps the command; 0 resumes.
    pub const HALT: u16 = 1 << 8;
    /// Bit 9, mode specific in CiA 402 ("change on set-point"); reserved on both reference devices.
    pub const BIT9: u16 = 1 << 9;
    /// MTR-DCI bit 11: jog positive while set.
    pub const MTR_JOG_POSITIVE: u16 = 1 << 11;
    /// MTR-DCI bit 12: jog negative while set.
    pub const MTR_JOG_NEGATIVE: u16 = 1 << 12;
    /// MTR-DCI bit 13: teach, take the current value.
    pub const MTR_TEACH: u16 = 1 << 13;
    /// MTR-DCI bit 14: HMI access locked.
    pub const MTR_HMI_LOCKED: u16 = 1 << 14;
    /// MTR-DCI bit 15: symmetrical ramp via PDO (the acceleration also brakes).
    pub const MTR_SYMMETRICAL_RAMP: u16 = 1 << 15;

    /// Bits 0..3 and 7, which carry the device-control command.
    pub const COMMAND_MASK: u16 = 0x008F;

    /// The controlword as it travels (little-endian, 2 bytes).
    pub const fn to_bytes(self) -> [u8; 2] {
        self.0.to_le_bytes()
    }
    /// The controlword from its 2 wire bytes.
    pub const fn from_bytes(b: [u8; 2]) -> Controlword {
        Controlword(u16::from_le_bytes(b))
    }
    /// Decodes a controlword from the first two bytes of `data` (an SDO payload or a PDO slice);
    /// `None` if fewer than two bytes are given.
    pub fn decode(data: &[u8]) -> Option<Controlword> {
        match data {
            [a, b, ..] => Some(Controlword::from_bytes([*a, *b])),
            _ => None,
        }
    }

    /// Whether every bit of `mask` is set.
    pub const fn has(self, mask: u16) -> bool {
        self.0 & mask == mask
    }
    /// The same controlword with the bits of `mask` set to `on`.
    #[must_use]
    pub const fn with(self, mask: u16, on: bool) -> Controlword {
        Controlword(if on { self.0 | mask } else { self.0 & !mask })
    }

    /// The device-control command of bits 0..3.
    pub const fn command(self) -> Command {
        if !self.has(Self::ENABLE_VOLTAGE) {
            Command::DisableVoltage
        } else if !self.has(Self::QUICK_STOP) {
            Command::QuickStop
        } else if !self.has(Self::SWITCH_ON) {
            Command::Shutdown
        } else if !self.has(Self::ENABLE_OPERATION) {
            Command::SwitchOn
        } else {
            Command::EnableOperation
        }
    }
    /// The same controlword with bits 0..3 replaced by `cmd` (mode bits, halt and bit 7 kept).
    #[must_use]
    pub const fn with_command(self, cmd: Command) -> Controlword {
        Controlword((self.0 & !0x000F) | cmd.controlword().0)
    }

    /// Bit 4: profile position "new set-point" / homing "start".
    pub const fn new_set_point(self) -> bool {
        self.has(Self::NEW_SET_POINT)
    }
    /// Bit 5: profile position "change set immediately".
    pub const fn change_set_immediately(self) -> bool {
        self.has(Self::CHANGE_SET_IMMEDIATELY)
    }
    /// Bit 6 read with the device's polarity: whether the set-point is relative.
    pub const fn is_relative(self, polarity: AbsRel) -> bool {
        let bit = self.has(Self::ABS_REL);
        match polarity {
            AbsRel::ZeroIsAbsolute => bit,
            AbsRel::ZeroIsRelative => !bit,
        }
    }
    /// The same controlword with bit 6 set for a relative (`true`) or absolute set-point.
    #[must_use]
    pub const fn with_relative(self, relative: bool, polarity: AbsRel) -> Controlword {
        let bit = match polarity {
            AbsRel::ZeroIsAbsolute => relative,
            AbsRel::ZeroIsRelative => !relative,
        };
        self.with(Self::ABS_REL, bit)
    }
    /// Bit 7: fault reset (level; the state machine looks for the rising edge).
    pub const fn fault_reset(self) -> bool {
        self.has(Self::FAULT_RESET)
    }
    /// Bit 8: halt.
    pub const fn halt(self) -> bool {
        self.has(Self::HALT)
    }
}

impl From<u16> for Controlword {
    fn from(v: u16) -> Self {
        Controlword(v)
    }
}

impl From<Controlword> for u16 {
    fn from(cw: Controlword) -> u16 {
        cw.0
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn command_table_values_decode_to_their_command() {
        for cmd in [
            Command::DisableVoltage,
            Command::QuickStop,
            Command::Shutdown,
            Command::SwitchOn,
            Command::EnableOperation,
        ] {
            assert_eq!(cmd.controlword().command(), cmd);
        }
        // Don't-care bits do not change the command (TLC5xx §5.2.2 table).
        assert_eq!(Controlword(0x0008).command(), Command::DisableVoltage);
        assert_eq!(Controlword(0x000B).command(), Command::QuickStop);
        assert_eq!(Controlword(0x000E).command(), Command::Shutdown);
        assert_eq!(Controlword(0x009F).command(), Command::EnableOperation);
    }

    #[test]
    fn bit6_polarity_round_trips_for_both_devices() {
        for pol in [AbsRel::ZeroIsAbsolute, AbsRel::ZeroIsRelative] {
            for rel in [false, true] {
                let cw = Controlword(0x001F).with_relative(rel, pol);
                assert_eq!(cw.is_relative(pol), rel);
            }
        }
        // §8.5 trace: 001Fh is a relative move on the TLC5xx as printed.
        assert!(Controlword(0x001F).is_relative(AbsRel::ZeroIsRelative));
        assert_eq!(
            Controlword(0x000F).with_relative(true, AbsRel::ZeroIsAbsolute),
            Controlword(0x004F)
        );
    }

    #[test]
    fn with_command_keeps_mode_bits() {
        let cw = Controlword(0x0170).with_command(Command::EnableOperation);
        assert_eq!(cw, Controlword(0x017F));
        assert_eq!(cw.with_command(Command::QuickStop), Controlword(0x0172));
        assert_eq!(Controlword::decode(&[0x1F]), None);
        assert_eq!(
            Controlword::decode(&[0x1F, 0x01, 9]),
            Some(Controlword(0x011F))
        );
    }
}
