//! CiA 402 (DSP402) drive profile: the controlword and statusword codecs, the device state
//! machine, the modes of operation with the profile position set-point handshake and the profile
//! velocity status, homing methods as data, and the object constants. One codec for both sides:
//! the coordinator (master) and the device simulators use the same bit layouts.
//!
//! Two reference devices speak it: the TLC5xx ([`TLC5XX`], seed 003) and the MTR-DCI in its
//! CiA 402 profile ([`MTR_DCI`], seed 000 §7.8–7.10). Where they differ, a [`DeviceProfile`]
//! field says how, and names the manual.
//!
//! ```
//! use drivers::cia402::{TLC5XX, controlword::Controlword, state::{State, next_controlword}};
//! use drivers::cia402::statusword::Statusword;
//! // Master side: decode the state, send the next step toward Operation enabled.
//! let state = State::from_statusword(Statusword(0x0040)).unwrap();
//! assert_eq!(next_controlword(state, Controlword(0)), Controlword(0x0006));
//! ```

pub mod controlword;
pub mod homing;
pub mod modes;
pub mod objects;
pub mod state;
pub mod statusword;

use controlword::AbsRel;
use homing::HomingMethod;
use modes::OperationMode;
use state::{FaultCoding, Flavour, QuickStopOption, State};
use statusword::Statusword;

/// How one device model implements CiA 402, where the manuals differ from each other or from
/// the standard. The simulator of a device and the master driving it use the same profile.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct DeviceProfile {
    /// The device, for diagnostics.
    pub name: &'static str,
    /// The transition table.
    pub flavour: Flavour,
    /// The polarity of controlword bit 6 in profile position mode.
    pub abs_rel: AbsRel,
    /// Whether controlword bit 5 "change set immediately" is honoured (the MTR-DCI ignores it
    /// and always queues).
    pub change_set_immediately: bool,
    /// The quick stop option class (605Ah).
    pub quick_stop: QuickStopOption,
    /// How the Fault state is coded in the statusword.
    pub fault_coding: FaultCoding,
    /// The value of statusword bit 9 "remote" while the field bus has control.
    pub remote_under_bus_control: bool,
    /// The modes of operation 6060h accepts.
    pub modes: &'static [OperationMode],
    /// The homing methods 6098h accepts.
    pub homing_methods: &'static [HomingMethod],
}

/// The TLC5xx (seed 003): CiA 402 transitions 1..16; bit 6 polarity as printed in the manual
/// (0 = relative, the digest's suggested default, erratum A1); change set immediately honoured;
/// stays in Quick stop active; Fault coded CiA 402 style (erratum A2); remote bit 0 under bus
/// control (erratum A3); modes 1, 3, 6, −1; homing methods 1, 2, 7, 11, 17, 18, 23, 27, 35.
pub const TLC5XX: DeviceProfile = DeviceProfile {
    name: "TLC5xx",
    flavour: Flavour::Cia402,
    abs_rel: AbsRel::ZeroIsRelative,
    change_set_immediately: true,
    quick_stop: QuickStopOption::StayInQuickStop,
    fault_coding: FaultCoding::Dsp402,
    remote_under_bus_control: false,
    modes: &[
        OperationMode::ProfilePosition,
        OperationMode::ProfileVelocity,
        OperationMode::Homing,
        OperationMode::TlcSigMode,
    ],
    homing_methods: &[
        HomingMethod::NegativeLimitIndex,
        HomingMethod::PositiveLimitIndex,
        HomingMethod::HomeSwitchPositiveIndex,
        HomingMethod::HomeSwitchNegativeIndex,
        HomingMethod::NegativeLimit,
        HomingMethod::PositiveLimit,
        HomingMethod::HomeSwitchPositive,
        HomingMethod::HomeSwitchNegative,
        HomingMethod::CurrentPosition,
    ],
};

/// The MTR-DCI in its CiA 402 profile (seed 000 §7.8–7.10): transitions 19, 20, 21; bit 6 as
/// CiA 402 (0 = absolute); no change set immediately; stays in Quick stop active (12 only on
/// Disable voltage); remote bit 1 under bus control (CiA 402); modes 1, 4, 6, −2; homing methods
/// 23, 27 and the hard-stop methods −17, −18.
pub const MTR_DCI: DeviceProfile = DeviceProfile {
    name: "MTR-DCI",
    flavour: Flavour::FestoMtrDci,
    abs_rel: AbsRel::ZeroIsAbsolute,
    change_set_immediately: false,
    quick_stop: QuickStopOption::StayInQuickStop,
    fault_coding: FaultCoding::Dsp402,
    remote_under_bus_control: true,
    modes: &[
        OperationMode::ProfilePosition,
        OperationMode::ProfileTorque,
        OperationMode::Homing,
        OperationMode::FestoDemo,
    ],
    homing_methods: &[
        HomingMethod::HomeSwitchPositive,
        HomingMethod::HomeSwitchNegative,
        HomingMethod::FestoHardStopNegative,
        HomingMethod::FestoHardStopPositive,
    ],
};

/// A generic CiA 402 drive (`shared/reference/plcopen-and-cia402-csp.md` §6, §7, §10): the
/// standard's transitions and bit-6 polarity (0 = absolute), change set immediately honoured,
/// quick stop option 2 (stop, then Switch on disabled: the profile's default 605Ah), remote bit
/// 1 under bus control; modes PP, PV, HM and the cyclic synchronous CSP, CSV, CST (6502h =
/// 03A5h); the homing methods that need no index pulse, and 35/37. A real drive's EDS narrows
/// the modes (its 6502h); the simulator of this profile offers them all.
pub const GENERIC: DeviceProfile = DeviceProfile {
    name: "CiA 402 drive",
    flavour: Flavour::Cia402,
    abs_rel: AbsRel::ZeroIsAbsolute,
    change_set_immediately: true,
    quick_stop: QuickStopOption::ToSwitchOnDisabled,
    fault_coding: FaultCoding::Dsp402,
    remote_under_bus_control: true,
    modes: &[
        OperationMode::ProfilePosition,
        OperationMode::ProfileVelocity,
        OperationMode::Homing,
        OperationMode::CyclicSyncPosition,
        OperationMode::CyclicSyncVelocity,
        OperationMode::CyclicSyncTorque,
    ],
    homing_methods: &[
        HomingMethod::NegativeLimit,
        HomingMethod::PositiveLimit,
        HomingMethod::HomeSwitchPositive,
        HomingMethod::HomeSwitchNegative,
        HomingMethod::CurrentPosition,
        HomingMethod::CurrentPosition37,
    ],
};

impl DeviceProfile {
    /// The statusword a device in `state` sends: the state pattern, bit 9 "remote" per the
    /// profile, and the bits of `dynamic` outside the state mask (warning, voltage enabled,
    /// internal limit, manufacturer bits, and the mode bits 10, 12, 13).
    ///
    /// The mode bits are left out in Not ready to switch on and Switch on disabled: the TLC5xx
    /// trace (§5.2.3) shows 0040h there but 0421h once Ready to switch on.
    pub const fn statusword(&self, state: State, dynamic: Statusword) -> Statusword {
        let mut extra = dynamic.0 & !Statusword::STATE_MASK & !Statusword::REMOTE;
        if matches!(state, State::NotReadyToSwitchOn | State::SwitchOnDisabled) {
            extra &= !Statusword::MODE_MASK;
        }
        if self.remote_under_bus_control {
            extra |= Statusword::REMOTE;
        }
        Statusword(state.pattern(self.fault_coding).0 | extra)
    }

    /// Whether 6060h accepts `mode` on this device.
    pub fn supports_mode(&self, mode: OperationMode) -> bool {
        self.modes.contains(&mode)
    }

    /// Whether 6098h accepts `method` on this device.
    pub fn supports_homing(&self, method: HomingMethod) -> bool {
        self.homing_methods.contains(&method)
    }
}
