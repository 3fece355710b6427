//! FHPP, the Festo Handling and Positioning Profile: one codec shared by the master (coordinator)
//! and the device simulators.
//!
//! - [`control`]: CCON, CPOS, CDIR and the master's 8 output bytes in record select and direct
//!   mode.
//! - [`status`]: SCON, SPOS, SDIR, the record status byte RSB and the drive's 8 input bytes.
//! - [`state`]: the FHPP state machine (S1..S6, T1..T11; S4 sub-states SA1..SA6, TA1..TA12) as a
//!   pure step function for simulators, and master-side helpers (bring-up, START/ACK/MC handshake).
//! - [`fpc`]: the Festo parameter channel, classic FPC (MTR-DCI) and enhanced EFPC (EMCA,
//!   CMMO-ST), with client and server state machines for the "no task in between" rule.
//! - [`pnu`]: parameter (PNU) tables of the three devices, lookup and write range checks.
//! - [`units`]: increments, SINC, gear/feed and percentage scalings, in integers.
//!
//! The three Festo devices differ in details the manuals (and the digests in
//! `shared/reference/seed-00{0,1,2}-*.md`) list; [`Variant`] makes each difference a decision in
//! one place instead of a condition spread through the code.
//!
//! ```
//! use drivers::fhpp::{ByteOrder, Variant, control::{Ccon, Cpos, OutputImage}};
//! // MTR-DCI, record select, drive enabled, homing edge (digest 000 §2.5, Tab. 5/11).
//! let out = OutputImage::record(Ccon::from_byte(0x03), Cpos::from_byte(0x05), 0);
//! assert_eq!(out.to_bytes(ByteOrder::Little), [0x03, 0x05, 0, 0, 0, 0, 0, 0]);
//! assert_eq!(Variant::MtrDci.max_record(), 31);
//! ```

pub mod control;
pub mod fpc;
pub mod pnu;
pub mod state;
pub mod status;
pub mod units;

/// Which Festo device speaks FHPP on the other end.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum Variant {
    /// Motor unit MTR-DCI-...-CO over CANopen (seed 000): 31 records, no chaining, position and
    /// force modes, classic FPC.
    MtrDci,
    /// Integrated drive EMCA-EC over CANopen (seed 002): 64 records with chaining, comparators,
    /// position/force/speed modes, EFPC.
    Emca,
    /// Stepper controller CMMO-ST over Modbus TCP (seed 001): 64 records with chaining,
    /// comparators, position/force/speed modes, EFPC.
    CmmoSt,
}

impl Variant {
    /// The device's entry in the [`crate::catalog`].
    pub const fn device(self) -> &'static crate::catalog::Device {
        match self {
            Variant::MtrDci => &crate::catalog::MTR_DCI,
            Variant::Emca => &crate::catalog::EMCA,
            Variant::CmmoSt => &crate::catalog::CMMO_ST,
        }
    }

    /// The highest record number control byte 3 may address in record select (record 0 =
    /// homing on every variant), from the catalog.
    pub const fn max_record(self) -> u8 {
        match self.device().records {
            Some(r) => r.last,
            None => 0,
        }
    }

    /// The multi-byte order of the cyclic image on this device's usual bus: CANopen is
    /// little-endian (MTR-DCI §5.4.4, EMCA p.125), Modbus TCP big-endian (CMMO-ST §4).
    pub const fn default_byte_order(self) -> ByteOrder {
        match self {
            Variant::MtrDci | Variant::Emca => ByteOrder::Little,
            Variant::CmmoSt => ByteOrder::Big,
        }
    }

    /// Whether the device has the speed control mode (CDIR.COM = 10). The MTR-DCI has only
    /// position and force (its 6502h = 0x29).
    pub const fn has_speed_mode(self) -> bool {
        !matches!(self, Variant::MtrDci)
    }

    /// Whether the device chains records by itself (RCB2, PNU 416), from the catalog. The
    /// MTR-DCI cannot (§5.5.1): the coordinator chains for it.
    pub const fn has_record_chaining(self) -> bool {
        match self.device().records {
            Some(r) => r.chaining,
            None => false,
        }
    }

    /// Whether CCON.BRAKE releases the brake (EMCA, CMMO-ST) or is reserved (MTR-DCI).
    pub const fn has_brake_bit(self) -> bool {
        !matches!(self, Variant::MtrDci)
    }

    /// Which parameter channel the device speaks in bytes 9..16.
    pub const fn parameter_channel(self) -> fpc::Channel {
        match self {
            Variant::MtrDci => fpc::Channel::Classic,
            Variant::Emca | Variant::CmmoSt => fpc::Channel::Enhanced,
        }
    }

    /// Whether the control mode `com` is one this device executes.
    pub const fn supports(self, com: ControlMode) -> bool {
        match com {
            ControlMode::Position | ControlMode::Force => true,
            ControlMode::Speed => self.has_speed_mode(),
            ControlMode::Reserved => false,
        }
    }
}

/// The order of multi-byte values on the wire.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum ByteOrder {
    /// Lower-value byte first (CANopen, EtherCAT, EtherNet/IP).
    Little,
    /// Most significant byte first (Modbus TCP, PROFINET; the PROFIBUS-style examples of the
    /// MTR-DCI manual §B.1.4).
    Big,
}

impl ByteOrder {
    /// `v` as 4 bytes in this order.
    pub const fn u32_bytes(self, v: u32) -> [u8; 4] {
        match self {
            ByteOrder::Little => v.to_le_bytes(),
            ByteOrder::Big => v.to_be_bytes(),
        }
    }
    /// 4 bytes in this order as a `u32`.
    pub const fn u32_from(self, b: [u8; 4]) -> u32 {
        match self {
            ByteOrder::Little => u32::from_le_bytes(b),
            ByteOrder::Big => u32::from_be_bytes(b),
        }
    }
    /// `v` as 2 bytes in this order.
    pub const fn u16_bytes(self, v: u16) -> [u8; 2] {
        match self {
            ByteOrder::Little => v.to_le_bytes(),
            ByteOrder::Big => v.to_be_bytes(),
        }
    }
    /// 2 bytes in this order as a `u16`.
    pub const fn u16_from(self, b: [u8; 2]) -> u16 {
        match self {
            ByteOrder::Little => u16::from_le_bytes(b),
            ByteOrder::Big => u16::from_be_bytes(b),
        }
    }
}

/// The FHPP operating mode, CCON.OPM / SCON.OPM (bits 7..6: OPM2, OPM1).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Default)]
pub enum Opm {
    /// 00: record select, the power-on default.
    #[default]
    RecordSelect,
    /// 01: direct mode (setpoints in the telegram).
    Direct,
    /// 10: reserved.
    Reserved2,
    /// 11: reserved.
    Reserved3,
}

impl Opm {
    /// The mode from the two bits (OPM2, OPM1) as a number 0..=3; higher bits are ignored.
    pub const fn from_bits(bits: u8) -> Opm {
        match bits & 0b11 {
            0 => Opm::RecordSelect,
            1 => Opm::Direct,
            2 => Opm::Reserved2,
            _ => Opm::Reserved3,
        }
    }
    /// The two bits (OPM2, OPM1) as a number 0..=3.
    pub const fn bits(self) -> u8 {
        match self {
            Opm::RecordSelect => 0,
            Opm::Direct => 1,
            Opm::Reserved2 => 2,
            Opm::Reserved3 => 3,
        }
    }
}

/// The control mode, CDIR.COM / SDIR.COM / RCB1.COM / RSB.COM (COM2, COM1).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Default)]
pub enum ControlMode {
    /// 00: position control.
    #[default]
    Position,
    /// 01: force/torque (current control; the MTR-DCI's "power operation").
    Force,
    /// 10: speed control (EMCA, CMMO-ST only).
    Speed,
    /// 11: reserved; in a record (RCB1) it marks the record invalid.
    Reserved,
}

impl ControlMode {
    /// The mode from the two bits (COM2, COM1) as a number 0..=3; higher bits are ignored.
    pub const fn from_bits(bits: u8) -> ControlMode {
        match bits & 0b11 {
            0 => ControlMode::Position,
            1 => ControlMode::Force,
            2 => ControlMode::Speed,
            _ => ControlMode::Reserved,
        }
    }
    /// The two bits (COM2, COM1) as a number 0..=3.
    pub const fn bits(self) -> u8 {
        match self {
            ControlMode::Position => 0,
            ControlMode::Force => 1,
            ControlMode::Speed => 2,
            ControlMode::Reserved => 3,
        }
    }
}

/// Reads bit `n` of `b`.
pub(crate) const fn bit(b: u8, n: u8) -> bool {
    b & (1 << n) != 0
}

/// `1 << n` if `on`, else 0.
pub(crate) const fn set(on: bool, n: u8) -> u8 {
    if on { 1 << n } else { 0 }
}
