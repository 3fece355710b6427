//! The CiA 402 and TLC5xx manufacturer objects the coordinator and the simulators share: index,
//! sub-index, name and data type, written once, so a simulator's dictionary and the master's PDO
//! mappings name the same constants.
//!
//! Objects marked "CiA 402" are standard objects neither manual lists with details; their types
//! are the standard's.
//!
//! ```
//! use drivers::cia402::objects::{self, TARGET_POSITION};
//! assert_eq!(TARGET_POSITION.mapping().to_u32(), 0x607A_0020);
//! assert_eq!(objects::TLC_RPDO4_MAPPING[1].to_u32(), 0x20E8_0010);
//! ```

use crate::canopen::Address;
use crate::canopen::od::{AccessType, DataType, EntryDef};
use crate::canopen::pdo::mapping::MappingEntry;

/// One object: where it lives and what it holds.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub struct Object {
    /// Index and sub-index.
    pub addr: Address,
    /// The manual's name.
    pub name: &'static str,
    /// The data type.
    pub data_type: DataType,
}

impl Object {
    const fn new(index: u16, sub: u8, name: &'static str, data_type: DataType) -> Object {
        Object {
            addr: Address::new(index, sub),
            name,
            data_type,
        }
    }
    /// The length in bits (0 for variable-length types).
    pub const fn bits(self) -> u8 {
        match self.data_type.size() {
            Some(n) if n <= 8 => (n * 8) as u8,
            _ => 0,
        }
    }
    /// The PDO mapping entry of the whole object (`index << 16 | sub << 8 | bits`).
    pub const fn mapping(self) -> MappingEntry {
        MappingEntry::new(self.addr.index, self.addr.sub, self.bits())
    }
    /// An object-dictionary definition with this address, name and type (default 0, no limits);
    /// the simulator adds access-specific details (`.mappable()`, defaults, limits).
    pub const fn entry(self, access: AccessType) -> EntryDef<'static> {
        EntryDef::new(self.addr, self.name, self.data_type, access)
    }
}

use DataType::{Integer8 as I8, Integer16 as I16, Integer32 as I32};
use DataType::{Unsigned16 as U16, Unsigned32 as U32};

/// 603Fh error code (U16).
pub const ERROR_CODE: Object = Object::new(0x603F, 0, "error code", U16);
/// 6040h controlword (U16).
pub const CONTROLWORD: Object = Object::new(0x6040, 0, "controlword", U16);
/// 6041h statusword (U16).
pub const STATUSWORD: Object = Object::new(0x6041, 0, "statusword", U16);
/// 605Ah quick stop option code (I16, CiA 402).
pub const QUICK_STOP_OPTION_CODE: Object = Object::new(0x605A, 0, "quick stop option code", I16);
/// 605Dh halt option code (I16; MTR-DCI fixed 1).
pub const HALT_OPTION_CODE: Object = Object::new(0x605D, 0, "halt option code", I16);
/// 605Eh fault reaction option code (I16; MTR-DCI fixed 2).
pub const FAULT_REACTION_OPTION_CODE: Object =
    Object::new(0x605E, 0, "fault reaction option code", I16);
/// 6060h modes of operation (I8).
pub const MODES_OF_OPERATION: Object = Object::new(0x6060, 0, "modes of operation", I8);
/// 6061h modes of operation display (I8).
pub const MODES_OF_OPERATION_DISPLAY: Object =
    Object::new(0x6061, 0, "modes of operation display", I8);
/// 6062h position demand value (I32, MTR-DCI).
pub const POSITION_DEMAND_VALUE: Object = Object::new(0x6062, 0, "position demand value", I32);
/// 6063h position actual value in increments (I32).
pub const POSITION_ACTUAL_INTERNAL: Object =
    Object::new(0x6063, 0, "position actual value (inc)", I32);
/// 6064h position actual value in user units (I32).
pub const POSITION_ACTUAL_VALUE: Object = Object::new(0x6064, 0, "position actual value", I32);
/// 6065h following error window (U32, CiA 402).
pub const FOLLOWING_ERROR_WINDOW: Object = Object::new(0x6065, 0, "following error window", U32);
/// 6067h position window (U32).
pub const POSITION_WINDOW: Object = Object::new(0x6067, 0, "position window", U32);
/// 6068h position window time (U16, ms).
pub const POSITION_WINDOW_TIME: Object = Object::new(0x6068, 0, "position window time", U16);
/// 606Ch velocity actual value (I32).
pub const VELOCITY_ACTUAL_VALUE: Object = Object::new(0x606C, 0, "velocity actual value", I32);
/// 607Ah target position (I32).
pub const TARGET_POSITION: Object = Object::new(0x607A, 0, "target position", I32);
/// 607Ch home offset (I32).
pub const HOME_OFFSET: Object = Object::new(0x607C, 0, "home offset", I32);
/// 607Dh:01 software position limit, minimum (I32).
pub const SOFTWARE_LIMIT_MIN: Object = Object::new(0x607D, 1, "min position limit", I32);
/// 607Dh:02 software position limit, maximum (I32).
pub const SOFTWARE_LIMIT_MAX: Object = Object::new(0x607D, 2, "max position limit", I32);
/// 607Fh max profile velocity (U32).
pub const MAX_PROFILE_VELOCITY: Object = Object::new(0x607F, 0, "max profile velocity", U32);
/// 6081h profile velocity (U32).
pub const PROFILE_VELOCITY: Object = Object::new(0x6081, 0, "profile velocity", U32);
/// 6083h profile acceleration (U32).
pub const PROFILE_ACCELERATION: Object = Object::new(0x6083, 0, "profile acceleration", U32);
/// 6084h profile deceleration (U32).
pub const PROFILE_DECELERATION: Object = Object::new(0x6084, 0, "profile deceleration", U32);
/// 6085h quick stop deceleration (U32).
pub const QUICK_STOP_DECELERATION: Object = Object::new(0x6085, 0, "quick stop deceleration", U32);
/// 6086h motion profile type (I16).
pub const MOTION_PROFILE_TYPE: Object = Object::new(0x6086, 0, "motion profile type", I16);
/// 6098h homing method (I8).
pub const HOMING_METHOD: Object = Object::new(0x6098, 0, "homing method", I8);
/// 6099h:01 homing speed during search for switch (TLC5xx: I32; CiA 402: U32).
pub const HOMING_SPEED_SWITCH: Object =
    Object::new(0x6099, 1, "speed during search for switch", I32);
/// 6099h:02 homing speed during search for zero (TLC5xx: I32; CiA 402: U32).
pub const HOMING_SPEED_ZERO: Object = Object::new(0x6099, 2, "speed during search for zero", I32);
/// 60F4h following error actual value (I32).
pub const FOLLOWING_ERROR_ACTUAL: Object =
    Object::new(0x60F4, 0, "following error actual value", I32);
/// 60FDh digital inputs (U32).
pub const DIGITAL_INPUTS: Object = Object::new(0x60FD, 0, "digital inputs", U32);
/// 60FEh:01 digital outputs (U32).
pub const DIGITAL_OUTPUTS: Object = Object::new(0x60FE, 1, "digital outputs", U32);
/// 60FFh target velocity (I32).
pub const TARGET_VELOCITY: Object = Object::new(0x60FF, 0, "target velocity", I32);
/// 6502h supported drive modes (U32).
pub const SUPPORTED_DRIVE_MODES: Object = Object::new(0x6502, 0, "supported drive modes", U32);

/// TLC5xx manufacturer objects that matter to motion (digest §3.4, §4, §5.3).
pub mod tlc {
    use super::{I32, Object, U16, U32};

    /// 2010h `p_maxDiff` following error limit (U32, inc).
    pub const P_MAX_DIFF: Object = Object::new(0x2010, 0, "p_maxDiff", U32);
    /// 2011h `p_win` standstill window (U16, inc).
    pub const P_WIN: Object = Object::new(0x2011, 0, "p_win", U16);
    /// 2012h `p_winTime` standstill window time (U16, ms).
    pub const P_WIN_TIME: Object = Object::new(0x2012, 0, "p_winTime", U16);
    /// 2040h `driveCtrl` (U16, one-shot bits 0 disable, 1 enable, 2 quick stop, 3 fault reset).
    pub const DRIVE_CTRL: Object = Object::new(0x2040, 0, "driveCtrl", U16);
    /// 2041h `driveStat` (U16: state code 2..9 in bits 3..0, 13 x_add_info, 14 x_end, 15 x_err).
    pub const DRIVE_STAT: Object = Object::new(0x2041, 0, "driveStat", U16);
    /// 2042h `xMode_act` SIG sub-mode (U16, bits 0..4).
    pub const X_MODE_ACT: Object = Object::new(0x2042, 0, "xMode_act", U16);
    /// 204Ch `SignQstop` per-source quick stop selection (U16).
    pub const SIGN_QSTOP: Object = Object::new(0x204C, 0, "SignQstop", U16);
    /// 204Fh `Flt_pDiff` following error class (U16, 1..3).
    pub const FLT_P_DIFF: Object = Object::new(0x204F, 0, "Flt_pDiff", U16);
    /// 2052h `SW_LimP` positive software limit (I32).
    pub const SW_LIM_P: Object = Object::new(0x2052, 0, "SW_LimP", I32);
    /// 2053h `SW_LimN` negative software limit (I32).
    pub const SW_LIM_N: Object = Object::new(0x2053, 0, "SW_LimN", I32);
    /// 2054h `SW_Enabl` software limit enable (U16, bits 5 P, 6 N).
    pub const SW_ENABL: Object = Object::new(0x2054, 0, "SW_Enabl", U16);
    /// 2089h `p_actusr` actual position in user units (I32, T_PDO4 bytes 0..3).
    pub const P_ACTUSR: Object = Object::new(0x2089, 0, "p_actusr", I32);
    /// 208Ah `v_jerkusr` profile generator speed (I32).
    pub const V_JERKUSR: Object = Object::new(0x208A, 0, "v_jerkusr", I32);
    /// 2090h `p_absPTP`: writing it starts an absolute SIG PTP move (I32, R_PDO4 bytes 0..3).
    pub const P_ABS_PTP: Object = Object::new(0x2090, 0, "p_absPTP", I32);
    /// 2091h `StatePTP` (U16: 15 x_err, 14 x_end, 13 setpoint reached, limit bits 0..7).
    pub const STATE_PTP: Object = Object::new(0x2091, 0, "StatePTP", U16);
    /// 2092h `p_relPTP`: writing it starts a relative SIG PTP move (I32).
    pub const P_REL_PTP: Object = Object::new(0x2092, 0, "p_relPTP", I32);
    /// 2093h `continue`: writing any value continues an interrupted SIG PTP move (U16).
    pub const CONTINUE: Object = Object::new(0x2093, 0, "continue", U16);
    /// 2094h `v_tarPTP` SIG PTP speed (I32).
    pub const V_TAR_PTP: Object = Object::new(0x2094, 0, "v_tarPTP", I32);
    /// 2095h `velocity`: writing it starts SIG speed mode (I32).
    pub const VELOCITY: Object = Object::new(0x2095, 0, "velocity", I32);
    /// 2096h `StateVEL` (U16).
    pub const STATE_VEL: Object = Object::new(0x2096, 0, "StateVEL", U16);
    /// 20E8h `v_tar16` fast-PTP speed (U16, R_PDO4 bytes 4..5).
    pub const V_TAR16: Object = Object::new(0x20E8, 0, "v_tar16", U16);
    /// 20E9h `ramp` fast-PTP ramp (U16, R_PDO4 bytes 6..7, default 600).
    pub const RAMP: Object = Object::new(0x20E9, 0, "ramp", U16);
    /// 20EBh `v_jerk16` actual profile speed (U16, T_PDO4 bytes 4..5, erratum A8).
    pub const V_JERK16: Object = Object::new(0x20EB, 0, "v_jerk16", U16);
    /// 20F0h `startHome` SIG homing start (U16).
    pub const START_HOME: Object = Object::new(0x20F0, 0, "startHome", U16);
    /// 20F1h `stateHome` (U16).
    pub const STATE_HOME: Object = Object::new(0x20F1, 0, "stateHome", U16);
    /// 20F3h `p_outHome` max run-out leaving the switch (U32, 0 = off).
    pub const P_OUT_HOME: Object = Object::new(0x20F3, 0, "p_outHome", U32);
    /// 20F4h `p_disHome` distance from the switching edge to the reference point (U32).
    pub const P_DIS_HOME: Object = Object::new(0x20F4, 0, "p_disHome", U32);
    /// 20F6h `startSetp` dimension setting (method 35) to this position (I32).
    pub const START_SETP: Object = Object::new(0x20F6, 0, "startSetp", I32);

    /// The bits of a SIG mode's state object (`StatePTP` 2091h, `StateVEL` 2096h, `stateHome`
    /// 20F1h, …; digest §4.1) and of `driveStat` 2041h bits 13..15.
    #[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Default)]
    pub struct SigState(pub u16);

    impl SigState {
        /// Bit 0: LIMP active.
        pub const LIMP: u16 = 1 << 0;
        /// Bit 1: LIMN active.
        pub const LIMN: u16 = 1 << 1;
        /// Bit 2: REF active.
        pub const REF: u16 = 1 << 2;
        /// Bit 3: STOP active.
        pub const STOP: u16 = 1 << 3;
        /// Bit 5: positive software limit.
        pub const SW_LIMP: u16 = 1 << 5;
        /// Bit 6: negative software limit.
        pub const SW_LIMN: u16 = 1 << 6;
        /// Bit 7: software stop.
        pub const SW_STOP: u16 = 1 << 7;
        /// Bit 13 `x_add_info`: mode specific (PTP: set-point reached; speed: set speed reached).
        pub const X_ADD_INFO: u16 = 1 << 13;
        /// Bit 14 `x_end`: 0 while the operation runs, 1 when done.
        pub const X_END: u16 = 1 << 14;
        /// Bit 15 `x_err`: the operation ended with an error.
        pub const X_ERR: u16 = 1 << 15;

        /// Whether every bit of `mask` is set.
        pub const fn has(self, mask: u16) -> bool {
            self.0 & mask == mask
        }
        /// The same value with the bits of `mask` set to `on`.
        #[must_use]
        pub const fn with(self, mask: u16, on: bool) -> SigState {
            SigState(if on { self.0 | mask } else { self.0 & !mask })
        }
        /// Bit 14 `x_end`.
        pub const fn x_end(self) -> bool {
            self.has(Self::X_END)
        }
        /// Bit 15 `x_err`.
        pub const fn x_err(self) -> bool {
            self.has(Self::X_ERR)
        }
    }
}

/// MTR-DCI manufacturer objects of its CiA 402 PDO mapping.
pub mod mtr {
    use super::{Object, U8};

    /// 2032h:01 record number (U8; 0 = direct set-point from 607Ah).
    pub const RECORD_NUMBER: Object = Object::new(0x2032, 1, "record number", U8);
}

use DataType::Unsigned8 as U8;

/// The TLC5xx R_PDO4 (static, "fast PTP"): p_absPTP, v_tar16, ramp. Receiving it starts an
/// absolute SIG PTP move.
pub const TLC_RPDO4_MAPPING: [MappingEntry; 3] = [
    tlc::P_ABS_PTP.mapping(),
    tlc::V_TAR16.mapping(),
    tlc::RAMP.mapping(),
];
/// The TLC5xx T_PDO4 (static): p_actusr, v_jerk16 (erratum A8: not v_jerkusr), StatePTP.
pub const TLC_TPDO4_MAPPING: [MappingEntry; 3] = [
    tlc::P_ACTUSR.mapping(),
    tlc::V_JERK16.mapping(),
    tlc::STATE_PTP.mapping(),
];
/// The TLC5xx default R_PDO2 (profile position): controlword, target position.
pub const TLC_RPDO2_MAPPING: [MappingEntry; 2] = [CONTROLWORD.mapping(), TARGET_POSITION.mapping()];
/// The TLC5xx default R_PDO3 (profile velocity): controlword, target velocity.
pub const TLC_RPDO3_MAPPING: [MappingEntry; 2] = [CONTROLWORD.mapping(), TARGET_VELOCITY.mapping()];
/// The TLC5xx default T_PDO2: statusword, position actual value.
pub const TLC_TPDO2_MAPPING: [MappingEntry; 2] =
    [STATUSWORD.mapping(), POSITION_ACTUAL_VALUE.mapping()];
/// The TLC5xx default T_PDO3: statusword, velocity actual value.
pub const TLC_TPDO3_MAPPING: [MappingEntry; 2] =
    [STATUSWORD.mapping(), VELOCITY_ACTUAL_VALUE.mapping()];
/// The MTR-DCI CiA 402 RPDO1 (static): controlword, record number, mode, target position.
pub const MTR_RPDO1_MAPPING: [MappingEntry; 4] = [
    CONTROLWORD.mapping(),
    mtr::RECORD_NUMBER.mapping(),
    MODES_OF_OPERATION.mapping(),
    TARGET_POSITION.mapping(),
];
/// The MTR-DCI CiA 402 RPDO2 (static): profile velocity, profile acceleration.
pub const MTR_RPDO2_MAPPING: [MappingEntry; 2] =
    [PROFILE_VELOCITY.mapping(), PROFILE_ACCELERATION.mapping()];
/// The MTR-DCI CiA 402 TPDO1 (static): statusword, record number, mode display, position.
pub const MTR_TPDO1_MAPPING: [MappingEntry; 4] = [
    STATUSWORD.mapping(),
    mtr::RECORD_NUMBER.mapping(),
    MODES_OF_OPERATION_DISPLAY.mapping(),
    POSITION_ACTUAL_VALUE.mapping(),
];

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn mappings_match_the_manuals_raw_values() {
        let raw = |m: &[MappingEntry]| -> heapless::Vec<u32, 8> {
            m.iter().map(|e| e.to_u32()).collect()
        };
        // TLC5xx §2.4 defaults.
        assert_eq!(
            raw(&TLC_RPDO2_MAPPING).as_slice(),
            &[0x6040_0010, 0x607A_0020]
        );
        assert_eq!(
            raw(&TLC_RPDO3_MAPPING).as_slice(),
            &[0x6040_0010, 0x60FF_0020]
        );
        assert_eq!(
            raw(&TLC_RPDO4_MAPPING).as_slice(),
            &[0x2090_0020, 0x20E8_0010, 0x20E9_0010]
        );
        assert_eq!(
            raw(&TLC_TPDO2_MAPPING).as_slice(),
            &[0x6041_0010, 0x6064_0020]
        );
        assert_eq!(
            raw(&TLC_TPDO3_MAPPING).as_slice(),
            &[0x6041_0010, 0x606C_0020]
        );
        assert_eq!(
            raw(&TLC_TPDO4_MAPPING).as_slice(),
            &[0x2089_0020, 0x20EB_0010, 0x2091_0010]
        );
        // MTR-DCI §7.4.
        assert_eq!(
            raw(&MTR_RPDO1_MAPPING).as_slice(),
            &[0x6040_0010, 0x2032_0108, 0x6060_0008, 0x607A_0020]
        );
        assert_eq!(
            raw(&MTR_RPDO2_MAPPING).as_slice(),
            &[0x6081_0020, 0x6083_0020]
        );
        assert_eq!(
            raw(&MTR_TPDO1_MAPPING).as_slice(),
            &[0x6041_0010, 0x2032_0108, 0x6061_0008, 0x6064_0020]
        );
        // Each fills at most one classic CAN frame.
        for m in [
            &TLC_RPDO4_MAPPING[..],
            &TLC_TPDO4_MAPPING,
            &MTR_RPDO1_MAPPING,
            &MTR_TPDO1_MAPPING,
        ] {
            assert!(m.iter().map(|e| u32::from(e.bits)).sum::<u32>() <= 64);
        }
    }

    #[test]
    fn sig_state_bits() {
        let st = tlc::SigState(0).with(tlc::SigState::X_END, true);
        assert!(st.x_end() && !st.x_err());
        assert_eq!(st.with(tlc::SigState::X_ERR, true).0, 0xC000);
    }

    #[test]
    fn entry_definitions_carry_the_constant() {
        let e = HOMING_METHOD.entry(AccessType::Rw);
        assert_eq!(e.addr, Address::new(0x6098, 0));
        assert_eq!(e.data_type, DataType::Integer8);
        assert!(!e.pdo_mappable);
        assert_eq!(HOMING_SPEED_ZERO.addr, Address::new(0x6099, 2));
    }
}
