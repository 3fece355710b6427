//! The Festo CMMO-ST's Modbus TCP interface, device side: FHPP over Modbus TCP as the
//! controller serves it (digest `seed-001-cmmo-st.md` §1.2, manual §4).
//!
//! The FHPP behaviour itself (state machine, records, parameters) is not here: it sits behind
//! [`FhppDevice`], which the transport-independent FHPP drive simulator implements. This module
//! adds only what the Modbus interface adds:
//!
//! - [`mbap`]: the wire format (MBAP header, deframing, the five function codes, exceptions);
//! - [`session`]: a sans-I/O server fed whole frames, connection events and time: register
//!   checks (start 0, quantity 4 or 8), the direction-split register space, FC 0x07 and
//!   0x2B/0x0E, one client at a time and the node-guard timeout with 47h/48h;
//! - [`tcp`]: the same on a real TCP socket, one std thread per server (no async runtime).
//!
//! The server adds nothing to the FHPP bytes: FHPP byte k is the k-th register data byte, so
//! register 0 = `(SCON << 8) | SPOS` (big-endian words, digest §1.2). The int32 order inside
//! bytes 5..8 is the FHPP codec's business ([`crate::fhpp::ByteOrder`]).
//!
//! ```
//! use drivers::sim::cmmo_st::{session::Session, Config, FhppDevice, Identification};
//! use drivers::time::Instant;
//!
//! struct PowerOn; // a stand-in device: the power-on status image, nothing more
//! impl FhppDevice for PowerOn {
//!     fn exchange(&mut self, _out: &[u8; 8], _now: Instant) -> [u8; 8] { [0x10, 0x04, 0, 0, 0, 0, 0, 0] }
//!     fn parameter(&mut self, _req: &[u8; 8], _now: Instant) -> [u8; 8] { [0; 8] }
//!     fn step_to(&mut self, _now: Instant) {}
//!     fn fault_number(&self) -> u16 { 0 }
//!     fn identification(&self) -> Identification<'_> { Identification::default() }
//!     fn master_control(&self) -> bool { true }
//! }
//!
//! let mut session = Session::new(Config::default()).unwrap();
//! let mut dev = PowerOn;
//! assert!(session.connect(&mut dev, Instant::ZERO));
//! // FC 0x03, start 0, 4 registers.
//! let req = [0, 1, 0, 0, 0, 6, 0, 0x03, 0, 0, 0, 4];
//! let mut out = [0; drivers::sim::cmmo_st::mbap::MAX_ADU];
//! let n = session.handle_frame(&req, &mut dev, Instant::ZERO, &mut out).unwrap().unwrap();
//! assert_eq!(&out[..n], &[0, 1, 0, 0, 0, 11, 0, 0x03, 8, 0x10, 0x04, 0, 0, 0, 0, 0, 0]);
//! ```

pub mod drive;
pub mod mbap;
pub mod session;
pub mod tcp;

use core::time::Duration;

use crate::time::Instant;

pub use session::Session;
pub use tcp::{Server, ServerConfig, StartError};

/// The FHPP device behind the Modbus interface: what the server needs from the drive
/// simulator. All FHPP semantics (edges, state machine, records, parameters) live behind it.
pub trait FhppDevice {
    /// The cyclic FHPP exchange: latch the 8 output bytes (CCON, CPOS, ...) and return the 8
    /// input bytes (SCON, SPOS, ...) as they are now.
    fn exchange(&mut self, output: &[u8; 8], now: Instant) -> [u8; 8];
    /// The parameter channel in bytes 9..16 of the "FHPP standard + FPC" profile (EFPC on the
    /// CMMO-ST): request in, response out.
    fn parameter(&mut self, request: &[u8; 8], now: Instant) -> [u8; 8];
    /// Advances the device (motion, timers, monitoring) to `now`.
    fn step_to(&mut self, now: Instant);
    /// The top fault number for FC 0x07 (PNU 205; 0 = no fault).
    fn fault_number(&self) -> u16;
    /// The strings of Read Device Identification (§4.3.3, Tab. 4.4).
    fn identification(&self) -> Identification<'_>;
    /// Whether the fieldbus (this Modbus interface) holds master control, PNU 125; it decides
    /// between diagnostic 47h and 48h when the connection is lost.
    fn master_control(&self) -> bool;
    /// The node-guard timeout expired: raise `lost.number()` with the reaction configured for
    /// it (warning up to "output stage off", §4.3.4). The default does nothing.
    fn connection_lost(&mut self, lost: ConnectionLost, now: Instant) {
        let _ = (lost, now);
    }
    /// A client connected: a 48h (or a 47h configured as a warning) clears itself on
    /// reconnection (App. D). The default does nothing.
    fn connection_established(&mut self, now: Instant) {
        let _ = now;
    }
}

/// Which diagnostic message a lost Modbus connection raises (App. D, 47h/48h).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum ConnectionLost {
    /// 47h: Modbus had master control (an error by default: the axis stops).
    WithMasterControl,
    /// 48h: Modbus did not have master control (warning or information).
    WithoutMasterControl,
}

impl ConnectionLost {
    /// The diagnostic number, as FC 0x07 and PNU 205 report it.
    pub const fn number(self) -> u8 {
        match self {
            ConnectionLost::WithMasterControl => 0x47,
            ConnectionLost::WithoutMasterControl => 0x48,
        }
    }
}

/// Read Device Identification objects (Tab. 4.4). The digest suggests filling them from PNUs
/// 122, 124, 101, 123, 120 and 121.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub struct Identification<'a> {
    /// Object 0x00 VendorName (PNU 122).
    pub vendor_name: &'a str,
    /// Object 0x01 ProductCode (the order number, PNU 124).
    pub product_code: &'a str,
    /// Object 0x02 MajorMinorRevision (firmware, PNU 101).
    pub revision: &'a str,
    /// Object 0x03 VendorUrl (PNU 123).
    pub vendor_url: &'a str,
    /// Object 0x04 ProductName (PNU 120).
    pub product_name: &'a str,
    /// Object 0x06 UserApplicationName (the project name, PNU 121).
    pub user_application_name: &'a str,
}

impl Default for Identification<'static> {
    /// A CMMO-ST-C5-1-LKP with firmware 1.4: the fixed PNU 122/123 strings (Tabs. B.16, B.17). The
    /// manual gives no order number (PNU 124, a gap), so the product code is the order code
    /// (type designation); the revision is PNU 101's four numerals.
    fn default() -> Self {
        // The fixed strings come from the catalog; `CMMO_ST` always has them.
        let id = crate::catalog::CMMO_ST.modbus_identity;
        let (vendor_name, vendor_url, product_name) = id.map_or(("", "", ""), |i| {
            (i.vendor_name, i.vendor_url, i.product_name)
        });
        Identification {
            vendor_name,
            product_code: product_name,
            revision: "1.4.0.0",
            vendor_url,
            product_name,
            user_application_name: "",
        }
    }
}

impl<'a> Identification<'a> {
    /// The object with this id, if the device has it (0x05 does not exist).
    pub fn object(&self, id: u8) -> Option<&'a str> {
        match id {
            0x00 => Some(self.vendor_name),
            0x01 => Some(self.product_code),
            0x02 => Some(self.revision),
            0x03 => Some(self.vendor_url),
            0x04 => Some(self.product_name),
            0x06 => Some(self.user_application_name),
            _ => None,
        }
    }
}

/// The device profile: how many bytes of process data each direction carries (§4.2).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Default)]
pub enum Profile {
    /// "FHPP standard": 8 bytes, 4 registers.
    #[default]
    Fhpp,
    /// "FHPP standard + FPC": 16 bytes, 8 registers; bytes 9..16 are the parameter channel.
    FhppFpc,
}

impl Profile {
    /// Registers per direction.
    pub const fn registers(self) -> u16 {
        match self {
            Profile::Fhpp => 4,
            Profile::FhppFpc => 8,
        }
    }
    /// Bytes per direction.
    pub const fn bytes(self) -> usize {
        2 * self.registers() as usize
    }
}

/// The Modbus interface parameters (FCT "Fieldbus" page): profile and node-guard timeout.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub struct Config {
    /// 8 or 16 bytes of process data.
    pub profile: Profile,
    /// Node-guard timeout, `None` = off; build it with [`node_guard_timeout`].
    pub timeout: Option<Duration>,
}

impl Default for Config {
    /// The factory setting: FHPP standard, timeout not activated (§4.2.1).
    fn default() -> Self {
        Config {
            profile: Profile::Fhpp,
            timeout: None,
        }
    }
}

/// A configuration value the device would not accept.
#[derive(Debug, Clone, Copy, PartialEq, Eq, thiserror::Error)]
pub enum ConfigError {
    /// The node-guard timeout is entered in 0..=5000 ms (§4.3.4).
    #[error("node-guard timeout {ms} ms is outside 0..=5000 ms")]
    TimeoutOutOfRange {
        /// The value given.
        ms: u32,
    },
}

/// The node-guard timeout as the device applies an entered value: 0 = off, 1..=99 ms is
/// raised to 100 ms, above 5000 ms is refused (§4.3.4).
pub fn node_guard_timeout(ms: u32) -> Result<Option<Duration>, ConfigError> {
    match ms {
        0 => Ok(None),
        1..=99 => Ok(Some(Duration::from_millis(100))),
        100..=5000 => Ok(Some(Duration::from_millis(u64::from(ms)))),
        _ => Err(ConfigError::TimeoutOutOfRange { ms }),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn node_guard_timeout_clamps_and_refuses() {
        assert_eq!(node_guard_timeout(0), Ok(None));
        assert_eq!(node_guard_timeout(1), Ok(Some(Duration::from_millis(100))));
        assert_eq!(node_guard_timeout(99), Ok(Some(Duration::from_millis(100))));
        assert_eq!(
            node_guard_timeout(250),
            Ok(Some(Duration::from_millis(250)))
        );
        assert_eq!(
            node_guard_timeout(5000),
            Ok(Some(Duration::from_millis(5000)))
        );
        assert_eq!(
            node_guard_timeout(5001),
            Err(ConfigError::TimeoutOutOfRange { ms: 5001 })
        );
    }

    #[test]
    fn identification_has_no_object_5() {
        let id = Identification::default();
        assert_eq!(id.object(0x00), Some("Festo AG & Co. KG"));
        assert_eq!(id.object(0x04), Some("CMMO-ST-C5-1-LKP"));
        assert_eq!(id.object(0x05), None);
        assert_eq!(id.object(0x07), None);
    }
}
