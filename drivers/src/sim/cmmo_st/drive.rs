//! The CMMO-ST simulator proper: the FHPP drive model (`FhppDrive`, variant CMMO-ST) behind
//! the Modbus TCP interface.

use super::{ConnectionLost, FhppDevice, Identification};
use crate::fhpp::Variant;
use crate::sim::fhpp_drive::{DriveConfig, DriveError, FhppDrive, PnuError};
use crate::time::Instant;

/// PNU 583 "direct start condition": 1 = a START while moving takes the new target.
pub const PNU_DIRECT_START_CONDITION: u16 = 583;

/// A CMMO-ST with the factory configuration of the FHPP drive model.
pub fn new_drive() -> Result<FhppDrive, DriveError> {
    FhppDrive::new(DriveConfig::new(Variant::CmmoSt))
}

/// Why [`commissioned`] could not build the drive.
#[derive(Debug, Clone, Copy, PartialEq, Eq, thiserror::Error)]
pub enum CommissionError {
    /// The drive model itself.
    #[error("CMMO-ST: {0}")]
    Drive(#[from] DriveError),
    /// A commissioning parameter was refused.
    #[error("CMMO-ST: PNU {pnu}: {source}")]
    Pnu {
        /// The PNU written.
        pnu: u16,
        /// The drive's refusal.
        source: PnuError,
    },
}

/// A CMMO-ST as commissioned for the coordinator (with FCT, before it goes on the network):
/// PNU 583 "direct start condition" = 1, so that a START while moving takes the new target.
/// The factory 0 ignores such a START, and the coordinator streams targets as STARTs while
/// moving; the 8-byte Modbus profile has no parameter channel to set it from the coordinator.
/// Every simulated CMMO-ST the coordinator drives (in memory, or `drive-sim`) is built here.
pub fn commissioned() -> Result<FhppDrive, CommissionError> {
    let mut drive = new_drive()?;
    drive
        .set_pnu(PNU_DIRECT_START_CONDITION, 1, 1)
        .map_err(|source| CommissionError::Pnu {
            pnu: PNU_DIRECT_START_CONDITION,
            source,
        })?;
    Ok(drive)
}

/// One status line for a running simulator: state, position, fault.
pub fn status_line(d: &FhppDrive) -> String {
    let i = d.input();
    let fault = d
        .fault_number()
        .map_or_else(|| "none".into(), |n| format!("{n:02X}h"));
    format!(
        "SCON {:02X}h SPOS {:02X}h pos {} inc referenced {} fault {fault}",
        i[0],
        i[1],
        d.axis().status().position,
        d.is_referenced()
    )
}

impl FhppDevice for FhppDrive {
    fn exchange(&mut self, output: &[u8; 8], now: Instant) -> [u8; 8] {
        FhppDrive::exchange(self, output, now)
    }
    fn parameter(&mut self, request: &[u8; 8], now: Instant) -> [u8; 8] {
        FhppDrive::parameter(self, request, now)
    }
    fn step_to(&mut self, now: Instant) {
        FhppDrive::step_to(self, now)
    }
    fn fault_number(&self) -> u16 {
        FhppDrive::fault_number(self).unwrap_or(0)
    }
    fn identification(&self) -> Identification<'_> {
        Identification::default()
    }
    fn master_control(&self) -> bool {
        !self.fct_control()
    }
    fn connection_lost(&mut self, lost: ConnectionLost, now: Instant) {
        self.fieldbus_lost(lost == ConnectionLost::WithMasterControl, now);
    }
    fn connection_established(&mut self, now: Instant) {
        self.fieldbus_restored(now);
    }
}
