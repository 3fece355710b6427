//! The statusword 6041h (U16): the device state bits and the mode-specific bits, with the
//! manuals' bit names (CiA 402; TLC5xx §3.3 of the digest; MTR-DCI Tab. C/4).
//!
//! ```
//! use drivers::cia402::statusword::Statusword;
//! let sw = Statusword::from_bytes([0x27, 0x14]); // 1427h
//! assert!(sw.operation_enabled() && sw.target_reached() && sw.set_point_acknowledge());
//! ```

/// A statusword value. Any 16-bit value is valid.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Default)]
pub struct Statusword(pub u16);

impl Statusword {
    /// Bit 0 "ready to switch on".
    pub const READY_TO_SWITCH_ON: u16 = 1 << 0;
    /// Bit 1 "switched on".
    pub const SWITCHED_ON: u16 = 1 << 1;
    /// Bit 2 "operation enabled".
    pub const OPERATION_ENABLED: u16 = 1 << 2;
    /// Bit 3 "fault".
    pub const FAULT: u16 = 1 << 3;
    /// Bit 4 "voltage enabled" (CiA 402, MTR-DCI). The TLC5xx manual names it "voltage disabled"
    /// and its traces always show 0.
    pub const VOLTAGE_ENABLED: u16 = 1 << 4;
    /// Bit 5 "quick stop", low active: 0 while a quick stop is active.
    pub const QUICK_STOP: u16 = 1 << 5;
    /// Bit 6 "switch on disabled".
    pub const SWITCH_ON_DISABLED: u16 = 1 << 6;
    /// Bit 7 "warning".
    pub const WARNING: u16 = 1 << 7;
    /// Bit 8: manufacturer specific. MTR-DCI "drive moves" (= SPOS.B4); unused on the TLC5xx.
    pub const MTR_DRIVE_MOVES: u16 = 1 << 8;
    /// Bit 9 "remote". TLC5xx: 0 under field-bus control in every trace (erratum A3).
    pub const REMOTE: u16 = 1 << 9;
    /// Bit 10 "target reached" (profile position, homing: at target or halted at standstill;
    /// profile velocity: set speed reached).
    pub const TARGET_REACHED: u16 = 1 << 10;
    /// Bit 11 "internal limit active" (TLC5xx: a limit switch or position was passed).
    pub const INTERNAL_LIMIT_ACTIVE: u16 = 1 << 11;
    /// Bit 12, mode specific: profile position "set-point acknowledge", homing "homing attained",
    /// profile velocity "speed = 0" (MTR-DCI profile torque: "is running").
    pub const BIT12: u16 = 1 << 12;
    /// Bit 13, mode specific: profile position "following error", homing "homing error", profile
    /// velocity "max slippage error" (MTR-DCI profile torque: "stroke limit reached").
    pub const BIT13: u16 = 1 << 13;
    /// Bit 14: manufacturer specific. MTR-DCI "teach acknowledge"; unused on the TLC5xx.
    pub const MTR_TEACH_ACK: u16 = 1 << 14;
    /// Bit 15: manufacturer specific. MTR-DCI "homing performed" (= SPOS.B7); unused on the TLC5xx.
    pub const MTR_HOMING_PERFORMED: u16 = 1 << 15;

    /// Profile position: bit 12 "set-point acknowledge".
    pub const SET_POINT_ACKNOWLEDGE: u16 = Self::BIT12;
    /// Profile position: bit 13 "following error".
    pub const FOLLOWING_ERROR: u16 = Self::BIT13;
    /// Homing: bit 12 "homing attained".
    pub const HOMING_ATTAINED: u16 = Self::BIT12;
    /// Homing: bit 13 "homing error".
    pub const HOMING_ERROR: u16 = Self::BIT13;
    /// Profile velocity: bit 12 "speed = 0".
    pub const SPEED_ZERO: u16 = Self::BIT12;
    /// Profile velocity: bit 13 "max slippage error".
    pub const MAX_SLIPPAGE: u16 = Self::BIT13;

    /// Bits 0, 1, 2, 3, 5, 6: the device state (CiA 402 mask 006Fh).
    pub const STATE_MASK: u16 = 0x006F;
    /// The bits the operation mode owns: target reached, 12 and 13.
    pub const MODE_MASK: u16 = Self::TARGET_REACHED | Self::BIT12 | Self::BIT13;

    /// The statusword as it travels (little-endian, 2 bytes).
    pub const fn to_bytes(self) -> [u8; 2] {
        self.0.to_le_bytes()
    }
    /// The statusword from its 2 wire bytes.
    pub const fn from_bytes(b: [u8; 2]) -> Statusword {
        Statusword(u16::from_le_bytes(b))
    }
    /// Decodes a statusword from the first two bytes of `data`; `None` if fewer are given.
    pub fn decode(data: &[u8]) -> Option<Statusword> {
        match data {
            [a, b, ..] => Some(Statusword::from_bytes([*a, *b])),
            _ => None,
        }
    }

    /// Whether every bit of `mask` is set.
    pub const fn has(self, mask: u16) -> bool {
        self.0 & mask == mask
    }
    /// The same statusword with the bits of `mask` set to `on`.
    #[must_use]
    pub const fn with(self, mask: u16, on: bool) -> Statusword {
        Statusword(if on { self.0 | mask } else { self.0 & !mask })
    }

    /// Bit 0.
    pub const fn ready_to_switch_on(self) -> bool {
        self.has(Self::READY_TO_SWITCH_ON)
    }
    /// Bit 1.
    pub const fn switched_on(self) -> bool {
        self.has(Self::SWITCHED_ON)
    }
    /// Bit 2.
    pub const fn operation_enabled(self) -> bool {
        self.has(Self::OPERATION_ENABLED)
    }
    /// Bit 3: the master's fault test on either device (digest 9.2 item 6).
    pub const fn fault(self) -> bool {
        self.has(Self::FAULT)
    }
    /// Bit 4.
    pub const fn voltage_enabled(self) -> bool {
        self.has(Self::VOLTAGE_ENABLED)
    }
    /// Whether a quick stop is active (bit 5 is low active).
    pub const fn quick_stop_active(self) -> bool {
        !self.has(Self::QUICK_STOP)
    }
    /// Bit 6.
    pub const fn switch_on_disabled(self) -> bool {
        self.has(Self::SWITCH_ON_DISABLED)
    }
    /// Bit 7.
    pub const fn warning(self) -> bool {
        self.has(Self::WARNING)
    }
    /// Bit 9.
    pub const fn remote(self) -> bool {
        self.has(Self::REMOTE)
    }
    /// Bit 10.
    pub const fn target_reached(self) -> bool {
        self.has(Self::TARGET_REACHED)
    }
    /// Bit 11.
    pub const fn internal_limit_active(self) -> bool {
        self.has(Self::INTERNAL_LIMIT_ACTIVE)
    }
    /// Bit 12 read as profile position "set-point acknowledge".
    pub const fn set_point_acknowledge(self) -> bool {
        self.has(Self::BIT12)
    }
    /// Bit 13 read as profile position "following error".
    pub const fn following_error(self) -> bool {
        self.has(Self::BIT13)
    }
    /// Bit 12 read as homing "homing attained".
    pub const fn homing_attained(self) -> bool {
        self.has(Self::BIT12)
    }
    /// Bit 13 read as homing "homing error".
    pub const fn homing_error(self) -> bool {
        self.has(Self::BIT13)
    }
    /// Bit 12 read as profile velocity "speed = 0".
    pub const fn speed_zero(self) -> bool {
        self.has(Self::BIT12)
    }
    /// Bit 13 read as profile velocity "max slippage error".
    pub const fn max_slippage(self) -> bool {
        self.has(Self::BIT13)
    }
}

impl From<u16> for Statusword {
    fn from(v: u16) -> Self {
        Statusword(v)
    }
}

impl From<Statusword> for u16 {
    fn from(sw: Statusword) -> u16 {
        sw.0
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn trace_values_read_as_the_manual_says() {
        // TLC5xx §8.4: 0421h = ready to switch on, quick stop not active, target reached.
        let sw = Statusword::from_bytes([0x21, 0x04]);
        assert!(sw.ready_to_switch_on() && !sw.switched_on() && sw.target_reached());
        assert!(!sw.quick_stop_active() && !sw.remote() && !sw.fault());
        // Quick stop active 0007h.
        assert!(Statusword(0x0007).quick_stop_active());
        assert_eq!(Statusword::decode(&[0x27, 0x10]), Some(Statusword(0x1027)));
        assert_eq!(Statusword::decode(&[]), None);
        assert_eq!(Statusword(0x1027).to_bytes(), [0x27, 0x10]);
        assert_eq!(
            Statusword(0).with(Statusword::BIT13, true),
            Statusword(0x2000)
        );
    }
}
