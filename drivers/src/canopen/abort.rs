//! SDO abort codes (CiA 301 §7.2.4.3.17), all of them, with their meanings.

macro_rules! abort_codes {
    ($($name:ident = $code:literal, $text:literal;)*) => {
        /// An SDO abort code. Codes the standard does not list (for example the manufacturer's
        /// `0800 xxxx` device error numbers) are kept as [`AbortCode::Other`].
        #[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
        pub enum AbortCode {
            $(
                #[doc = $text]
                $name,
            )*
            /// A code the standard does not define; the raw value.
            Other(u32),
        }

        impl AbortCode {
            /// Every code CiA 301 defines.
            pub const ALL: &'static [AbortCode] = &[$(AbortCode::$name,)*];

            /// The 32-bit code as sent in bytes 4..=7 of the abort frame.
            pub const fn code(self) -> u32 {
                match self {
                    $(AbortCode::$name => $code,)*
                    AbortCode::Other(c) => c,
                }
            }

            /// The code for a raw value; unknown values become [`AbortCode::Other`].
            pub const fn from_code(code: u32) -> AbortCode {
                match code {
                    $($code => AbortCode::$name,)*
                    c => AbortCode::Other(c),
                }
            }

            /// The meaning CiA 301 gives the code.
            pub const fn description(self) -> &'static str {
                match self {
                    $(AbortCode::$name => $text,)*
                    AbortCode::Other(c) if c >> 16 == 0x0800 => "manufacturer-specific error",
                    AbortCode::Other(_) => "unknown abort code",
                }
            }
        }
    };
}

abort_codes! {
    ToggleBit = 0x0503_0000, "Toggle bit not alternated";
    Timeout = 0x0504_0000, "SDO protocol timed out";
    InvalidCommand = 0x0504_0001, "Client/server command specifier not valid or unknown";
    InvalidBlockSize = 0x0504_0002, "Invalid block size (block mode only)";
    InvalidSequence = 0x0504_0003, "Invalid sequence number (block mode only)";
    CrcError = 0x0504_0004, "CRC error (block mode only)";
    OutOfMemory = 0x0504_0005, "Out of memory";
    UnsupportedAccess = 0x0601_0000, "Unsupported access to an object";
    WriteOnly = 0x0601_0001, "Attempt to read a write only object";
    ReadOnly = 0x0601_0002, "Attempt to write a read only object";
    NoObject = 0x0602_0000, "Object does not exist in the object dictionary";
    NotMappable = 0x0604_0041, "Object cannot be mapped to the PDO";
    PdoLength = 0x0604_0042, "The number and length of the objects to be mapped would exceed PDO length";
    ParamIncompatible = 0x0604_0043, "General parameter incompatibility reason";
    InternalIncompatible = 0x0604_0047, "General internal incompatibility in the device";
    Hardware = 0x0606_0000, "Access failed due to a hardware error";
    TypeMismatch = 0x0607_0010, "Data type does not match, length of service parameter does not match";
    TooLong = 0x0607_0012, "Data type does not match, length of service parameter too high";
    TooShort = 0x0607_0013, "Data type does not match, length of service parameter too low";
    NoSubIndex = 0x0609_0011, "Sub-index does not exist";
    InvalidValue = 0x0609_0030, "Invalid value for parameter (download only)";
    ValueTooHigh = 0x0609_0031, "Value of parameter written too high (download only)";
    ValueTooLow = 0x0609_0032, "Value of parameter written too low (download only)";
    MaxLessThanMin = 0x0609_0036, "Maximum value is less than minimum value";
    NoResource = 0x060A_0023, "Resource not available: SDO connection";
    General = 0x0800_0000, "General error";
    CannotStore = 0x0800_0020, "Data cannot be transferred or stored to the application";
    LocalControl = 0x0800_0021, "Data cannot be transferred or stored to the application because of local control";
    DeviceState = 0x0800_0022, "Data cannot be transferred or stored to the application because of the present device state";
    NoDictionary = 0x0800_0023, "Object dictionary dynamic generation fails or no object dictionary is present";
    NoData = 0x0800_0024, "No data available";
}

impl AbortCode {
    /// The code as the four little-endian bytes of the abort frame (0607 0013h -> `13 00 07 06`).
    pub const fn to_le_bytes(self) -> [u8; 4] {
        self.code().to_le_bytes()
    }
}

impl core::fmt::Display for AbortCode {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        let c = self.code();
        write!(
            f,
            "{:04X} {:04X}h ({})",
            c >> 16,
            c & 0xFFFF,
            self.description()
        )
    }
}

impl core::error::Error for AbortCode {}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn every_code_round_trips() {
        assert_eq!(AbortCode::ALL.len(), 31);
        for &a in AbortCode::ALL {
            assert_eq!(AbortCode::from_code(a.code()), a);
        }
        assert_eq!(
            AbortCode::from_code(0x0800_1234),
            AbortCode::Other(0x0800_1234)
        );
        assert_eq!(
            AbortCode::Other(0x0800_1234).description(),
            "manufacturer-specific error"
        );
    }

    #[test]
    fn manual_byte_order() {
        // TLC5xx manual p.7-5: 0607 0013h is sent as bytes 4..7 = 13 00 07 06.
        assert_eq!(AbortCode::TooShort.to_le_bytes(), [0x13, 0x00, 0x07, 0x06]);
        assert_eq!(
            AbortCode::NoObject.to_string(),
            "0602 0000h (Object does not exist in the object dictionary)"
        );
    }
}
